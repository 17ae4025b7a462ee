"""End-to-end tests of `prepare` on a tiny synthetic dataroot."""

import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from sianms_cli.data.cache import decode_roi_features, read_dataset, roi_feature_shape
from sianms_cli.data.index import build_pair_index
from sianms_cli.detection2d.external import ExternalDetections
from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError
from sianms_cli.metrics.boxes import LABEL
from sianms_cli.metrics.dataset import ego_poses, eval_split, ground_truth
from sianms_cli.metrics.regions import centers_in_ego, overlap_bits, region_mask
from sianms_cli.geometry.frustum import points_in_frustum, rotate_from_frustum
from sianms_cli.geometry.boxes import points_in_boxes
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.sample_rigs import sample_rigs
from sianms_cli.prepare import sample as prepare_module
from sianms_cli.prepare.config import PrepareConfig
from sianms_cli.prepare.job import run as prepare
from sianms_cli.reporting.dataset_summary import summarize
from sianms_cli.synth.generate import SynthConfig, run as run_synth


@pytest.fixture(scope="module")
def dataroot(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth")
    run_synth(SynthConfig(scenes=2, image_scale=0.25, scene_seconds=1.5, seed=3), root)
    return root


@pytest.fixture(scope="module")
def config(dataroot):
    return PrepareConfig(str(dataroot), "v1.0-mini", "mini_train", seed=5)


@pytest.fixture(scope="module")
def cache(config, tmp_path_factory):
    out = tmp_path_factory.mktemp("cache") / "c"
    prepare(config, out)
    return out


def file_bytes(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_writes_three_datasets_and_a_manifest(cache, config):
    manifest = json.loads((cache / "manifest.json").read_text())
    assert manifest["complete"] and manifest["schema_version"] == 1
    assert manifest["config"]["fill_missed"] is True  # a training split
    assert manifest["counts"]["samples"] == 3 and manifest["counts"]["detections"] > 10
    for name in ("detections", "frustums", "pairs"):
        files = sorted((cache / name).glob("*.parquet"))
        assert [f.name for f in files] == ["scene-0061.parquet"]
        metadata = pq.read_schema(files[0]).metadata
        assert metadata[b"sianms.dataset"] == name.encode() and metadata[b"sianms.schema_version"] == b"1"
        assert pq.ParquetFile(files[0]).metadata.row_group(0).column(0).compression == "ZSTD"
        assert manifest["files"][f"{name}/scene-0061.parquet"]["rows"] == pq.read_table(files[0]).num_rows
    detections = read_dataset(cache, "detections")
    shape = roi_feature_shape(cache / "detections" / "scene-0061.parquet")
    assert shape == (64, 7, 7)
    features = decode_roi_features(detections.column("roi_feature"), shape, cache / "detections")
    assert features.dtype == np.float16 and features.shape == (detections.num_rows, 64, 7, 7)
    assert np.isfinite(features).all() and features.astype(np.float64).std() > 0  # float16 sums overflow
    sources = set(detections.column("source").to_pylist())
    assert sources == {"detector", "ground_truth"}


def test_frustum_points_lie_in_the_frustum_with_right_labels(cache, config):
    db = NuScenesDB(config.dataroot, config.version)
    frustums = read_dataset(cache, "frustums").to_pylist()
    detections = {r["detection_id"]: r for r in read_dataset(cache, "detections").drop(["roi_feature"]).to_pylist()}
    checked_labels = 0
    for row in frustums:
        det = detections[row["detection_id"]]
        points = np.stack([row["x"], row["y"], row["z"]], axis=1).astype(np.float64).reshape(-1, 3)
        points_cam = rotate_from_frustum(points, row["rot_angle"])
        _, _, intrinsic = db.calibration_of(row["sample_data_token"])
        box2d = np.array([det["x1"], det["y1"], det["x2"], det["y2"]], dtype=np.float32).astype(np.float64)
        grown = box2d + np.array([-1e-3, -1e-3, 1e-3, 1e-3])  # float32 storage of points and box
        assert points_in_frustum(points_cam, grown, intrinsic, min_depth=0.999).all()
        assert row["num_points"] == len(points)
        if row["box_center_cam"] is not None and len(points):
            inside = points_in_boxes(points_cam, np.array([row["box_center_cam"]]), np.array([row["box_size"]]),
                                     np.array([row["box_rotation_cam"]]))[0]
            assert (inside == np.array(row["label"], dtype=bool)).mean() > 0.98  # float32 rounding at faces
            checked_labels += int(np.sum(row["label"]))
        elif row["box_center_cam"] is None:
            assert not any(row["label"])
    assert checked_labels > 50


def test_pairs_only_contiguous_cameras_and_same_instance(cache, config):
    db = NuScenesDB(config.dataroot, config.version)
    detections = {r["detection_id"]: r for r in read_dataset(cache, "detections").drop(["roi_feature"]).to_pylist()}
    pairs = read_dataset(cache, "pairs").to_pylist()
    assert pairs
    rigs, _ = sample_rigs(db, [pairs[0]["sample_token"]])
    contiguous = {frozenset((rigs[0].channels[a], rigs[0].channels[b])) for a, b in rigs[0].contiguous_pairs}
    for pair in pairs:
        ref, pos = detections[pair["reference_detection_id"]], detections[pair["positive_detection_id"]]
        assert ref["instance_token"] == pos["instance_token"] == pair["instance_token"]
        assert frozenset((ref["camera"], pos["camera"])) in contiguous
        assert (ref["camera"], pos["camera"]) == (pair["camera_a"], pair["camera_b"])
        assert ref["sample_token"] == pos["sample_token"] == pair["sample_token"]
    # Every instance detected in two contiguous cameras of one sample gives a pair.
    by_sample = {}
    for det in detections.values():
        if det["instance_token"]:
            by_sample.setdefault((det["sample_token"], det["instance_token"]), set()).add(det["camera"])
    expected = sum(1 for cams in by_sample.values() for pair in contiguous if pair <= cams)
    assert expected == len(pairs)
    index = build_pair_index(cache)
    for (scene, pair_name), instances in index.items():
        for instance, ids in instances.items():
            for det_id in ids:
                assert detections[det_id]["instance_token"] == instance and detections[det_id]["camera"] in pair_name


def metrics_overlap(db, split):
    """The overlap region as `sianms metrics` finds it: {annotation token: (in overlap, is a car, pair bits)}."""
    the_split = eval_split(db, split)
    boxes, rows = ground_truth(db, the_split)
    rotation, translation = ego_poses(db, the_split)
    rigs, rig_of_sample = sample_rigs(db, the_split.sample_tokens)
    bits = overlap_bits(boxes, centers_in_ego(boxes, rotation, translation), rigs, rig_of_sample)
    kept = region_mask("overlap", bits, len(boxes))
    tokens = db.table("sample_annotation").tokens[rows]
    return bits.pair_names, {str(token): (bool(keep), label == LABEL["car"], int(bit))
                             for token, keep, label, bit in zip(tokens, kept, boxes["label"], bits.bits)}


def test_prepare_info_and_metrics_agree_on_the_overlap_region(config, tmp_path):
    # mini_val holds this dataset's cars in the overlap region; filling in missed objects makes
    # prepare list every car it projects, as on a training split.
    val = PrepareConfig(config.dataroot, config.version, "mini_val", seed=5, fill_missed=True)
    cache = prepare(val, tmp_path / "val").out
    db = NuScenesDB(config.dataroot, config.version)
    pair_names, metrics = metrics_overlap(db, val.split)
    # prepare: each associated detection lists exactly the pairs of its camera whose overlap
    # holds its annotation's centre, and a pair is center_in_overlap exactly when its pair bit is set.
    detections = read_dataset(cache, "detections").select(["detection_id", "camera", "annotation_token",
                                                            "overlap_pairs"]).to_pylist()
    marked_cars = set()
    for det in detections:
        if det["annotation_token"] is None:
            assert det["overlap_pairs"] == []
            continue
        _, car, bit = metrics[det["annotation_token"]]
        assert det["overlap_pairs"] == [name for k, name in enumerate(pair_names)
                                        if bit >> k & 1 and det["camera"] in name.split("|")]
        if car and det["overlap_pairs"]:
            marked_cars.add(det["annotation_token"])
    annotation_of = {det["detection_id"]: det["annotation_token"] for det in detections}
    pairs = read_dataset(cache, "pairs").to_pylist()
    assert any(pair["center_in_overlap"] for pair in pairs)
    for pair in pairs:
        bit = metrics[annotation_of[pair["reference_detection_id"]]][2]
        assert pair["center_in_overlap"] == bool(bit >> pair_names.index(pair["pair"]) & 1)
    # Prepare marks every car of the overlap region it has a detection of (all but those hidden
    # behind nearer objects in every image: no detector finds them, and they are not filled in).
    in_overlap_cars = {token for token, (keep, car, _) in metrics.items() if keep and car}
    detected = {det["annotation_token"] for det in detections}
    assert marked_cars and marked_cars == in_overlap_cars & detected
    # info: its count of cars in the overlap over the whole dataset is the metrics' count over both splits.
    everything = {**metrics, **metrics_overlap(db, "mini_train")[1]}
    cars_in_overlap = sum(keep and car for keep, car, _ in everything.values())
    assert summarize(db, max_sweeps=0)["car_annotations_in_overlap"] == cars_in_overlap


def test_same_seed_same_bytes_and_independent_of_workers_and_shards(cache, config, tmp_path):
    prepare(config, tmp_path / "again")
    assert file_bytes(tmp_path / "again") == file_bytes(cache)
    other = PrepareConfig(config.dataroot, config.version, "mini_train", seed=6)
    prepare(other, tmp_path / "other")
    a = pq.read_table(cache / "detections" / "scene-0061.parquet").column("x1").to_pylist()
    b = pq.read_table(tmp_path / "other" / "detections" / "scene-0061.parquet").column("x1").to_pylist()
    assert a != b


def test_shards_and_two_workers_give_the_same_files(config, dataroot, tmp_path):
    # A split of two scenes (custom split file) run as shard 0/2 and 1/2, then as 2 workers.
    (dataroot / "v1.0-mini" / "splits.json").write_text(json.dumps({"both": ["scene-0061", "scene-0103"]}))
    both = PrepareConfig(config.dataroot, config.version, "both", seed=5)
    first = prepare(both, tmp_path / "sharded", shard="0/2")
    assert first.shards_run == ["scene-0061"] and not first.manifest["complete"]
    second = prepare(both, tmp_path / "sharded", shard="1/2")
    assert second.shards_run == ["scene-0103"] and second.manifest["complete"]
    prepare(both, tmp_path / "workers", workers=2)
    assert file_bytes(tmp_path / "sharded") == file_bytes(tmp_path / "workers")


def test_a_run_killed_half_way_then_rerun_gives_the_same_output(config, dataroot, cache, tmp_path, monkeypatch):
    out = tmp_path / "killed"
    calls = {"n": 0}
    original = prepare_module.Preparer.sample

    def dies_on_the_third_sample(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt  # as a kill: nothing cleans up
        return original(self, *args, **kwargs)

    monkeypatch.setattr(prepare_module.Preparer, "sample", dies_on_the_third_sample)
    with pytest.raises(KeyboardInterrupt):
        prepare(config, out)
    assert not list((out / "detections").glob("*.parquet"))
    assert not list(out.rglob("*.partial"))  # the interrupted shard's temporary files are removed
    manifest = json.loads((out / "manifest.json").read_text())
    assert (manifest["complete"], manifest["shards_expected"], manifest["missing_shards"]) == (False, 1, ["scene-0061"])
    monkeypatch.setattr(prepare_module.Preparer, "sample", original)
    result = prepare(config, out)
    assert result.shards_run == ["scene-0061"]
    assert not list(out.rglob("*.partial"))
    assert file_bytes(out) == file_bytes(cache)
    # A finished shard is skipped on the next run.
    assert prepare(config, out).shards_skipped == ["scene-0061"]


def test_bad_inputs_fail_clearly_and_write_nothing(config, dataroot, tmp_path):
    with pytest.raises(SianmsError, match="unknown detector 'yolo'"):
        PrepareConfig(config.dataroot, config.version, "mini_train", detector="yolo")
    bad = tmp_path / "dets.json"
    bad.write_text(json.dumps([{"sample_data_token": "nope", "x1": 0, "y1": 0, "x2": 5, "y2": 5,
                                "score": 0.9, "class": "car"}]))
    out = tmp_path / "out"
    with pytest.raises(DataFormatError, match="record nope.*no such sample_data"):
        prepare(PrepareConfig(config.dataroot, config.version, "mini_train", detector=f"file:{bad}"), out)
    assert not out.exists()
    with pytest.raises(SianmsError, match="needs --weights"):
        prepare(PrepareConfig(config.dataroot, config.version, "mini_train", backbone="resnet50-c4"), out)
    assert not out.exists()
    with pytest.raises(SianmsError, match="--shard"):
        prepare(config, out, shard="3/2")


def test_refuses_another_config_unless_overwrite(cache, config, tmp_path):
    other = PrepareConfig(config.dataroot, config.version, "mini_train", seed=99)
    with pytest.raises(OutputExistsError, match="differs in: seed"):
        prepare(other, cache)
    (tmp_path / "x.txt").write_text("")
    with pytest.raises(OutputExistsError, match="not empty"):
        prepare(config, tmp_path)


def test_external_detections_file(config, dataroot, tmp_path):
    db = NuScenesDB(config.dataroot, config.version)
    scene = db.table("scene").tokens[list(db.table("scene").column("name")).index("scene-0061")]
    front = db.keyframe_data(db.sample_tokens_of_scene(scene)[0])["CAM_FRONT"]
    path = tmp_path / "dets.json"
    path.write_text(json.dumps({"detections": [
        {"sample_data_token": front, "x1": 10.0, "y1": 20.0, "x2": 60.0, "y2": 70.0, "score": 0.7, "class": "car"},
        {"sample_data_token": front, "x1": 0.0, "y1": 0.0, "x2": 5.0, "y2": 5.0, "score": 0.9, "class": "truck"}]}))
    external = PrepareConfig(config.dataroot, config.version, "mini_train", detector=f"file:{path}", fill_missed=False)
    result = prepare(external, tmp_path / "out")
    assert result.manifest["config"]["fill_missed"] is False
    assert len(result.manifest["config"]["detector_sha256"]) == 64
    detections = read_dataset(tmp_path / "out", "detections").drop(["roi_feature"]).to_pylist()
    assert [(d["sample_data_token"], d["class"], d["x1"], d["score"]) for d in detections] == [
        (front, "car", 10.0, pytest.approx(0.7))]  # the truck is not a prepared class
    (tmp_path / "bad.json").write_text(json.dumps([{"sample_data_token": front, "x1": 5, "y1": 0, "x2": 1,
                                                    "y2": 5, "score": 0.5, "class": "car"}]))
    with pytest.raises(DataFormatError, match="x1 < x2"):
        prepare(PrepareConfig(config.dataroot, config.version, "mini_train", detector=f"file:{tmp_path / 'bad.json'}"),
                tmp_path / "out2")
    width, height = (int(db.table("sample_data").column(name)[db.table("sample_data").indices([front])[0]])
                     for name in ("width", "height"))
    beyond = [(width, 10, width + 40, 50), (-40, 10, 0, 50), (10, height, 50, height + 30), (10, -30, 50, 0)]
    for row, box in enumerate(beyond):
        boxes = [dict(zip(("x1", "y1", "x2", "y2"), (10, 20, 60, 70))), dict(zip(("x1", "y1", "x2", "y2"), box))]
        path.write_text(json.dumps([{"sample_data_token": front, **b, "score": 0.5, "class": "car"} for b in boxes]))
        with pytest.raises(DataFormatError, match=rf"^{path}: record {front}: field 'x1/y1/x2/y2': row 1: "
                                                  "box lies wholly outside its image"):
            prepare(PrepareConfig(config.dataroot, config.version, "mini_train", detector=f"file:{path}"),
                    tmp_path / f"beyond{row}")
    path.write_text(json.dumps([{"sample_data_token": front, "x1": -5.0, "y1": -5.0, "x2": width + 5.0,
                                 "y2": height + 5.0, "score": 0.5, "class": "car"}]))
    ExternalDetections(path, db, ("car",))  # reaching past every border is a detector's habit: accepted
    # ... but not by more than the image: 1e9 px had run ROI Align out of memory, 1e308 became inf
    for row, box in enumerate([(-1e9, -1e9, 1e9, 1e9), (10, 20, 1e308, 70), (-width - 1, 20, 60, 70)]):
        path.write_text(json.dumps([{"sample_data_token": front, **dict(zip(("x1", "y1", "x2", "y2"), box)),
                                     "score": 0.5, "class": "car"}]))
        with pytest.raises(DataFormatError, match=rf"^{path}: record {front}: field 'x1/y1/x2/y2': row 0: box reaches "
                                                  "more than its image's size past the image"):
            ExternalDetections(path, db, ("car",))
    for field in ("sample_data_token", "class"):  # numpy drops a trailing NUL: "car\0" had been read as "car"
        row = {"sample_data_token": front, "x1": 10, "y1": 20, "x2": 60, "y2": 70, "score": 0.5, "class": "car"}
        row[field] += "\u0000"
        path.write_text(json.dumps([row]))
        with pytest.raises(DataFormatError, match=rf"^{path}: field '{field}': row 0: expected a string without NUL$"):
            ExternalDetections(path, db, ("car",))


def test_readable_by_pandas_if_installed(cache):
    pandas = pytest.importorskip("pandas")
    frame = pandas.read_parquet(cache / "detections")
    assert len(frame) > 0 and "roi_feature" in frame.columns
