import hashlib
import json

import numpy as np
import pytest

from sianms_cli import __version__
from sianms_cli.errors import OutputExistsError, SianmsError
from sianms_cli.geometry.boxes import count_points_in_boxes
from sianms_cli.geometry.transforms import apply_transform, sensor_to_global
from sianms_cli.nuscenes.tables import SENSORS
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.synth import generate
from sianms_cli.provenance import numeric_platform
from sianms_cli.synth.generate import MARKER_NAME, SynthConfig, run, scene_names_for


def _digest(root):
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_tables_are_consistent(tiny_dataroot):
    db = NuScenesDB(tiny_dataroot, "v1.0-mini")
    assert len(db.table("scene")) == 2
    assert len(db.table("sample")) == 6
    assert len(db.table("sample_data")) == 6 * 7 + 2 * 2 * 9  # + 9 LiDAR sweeps between keyframes
    for scene in db.table("scene").tokens:
        samples = db.sample_tokens_of_scene(scene)
        assert len(samples) == 3
        for sample in samples:
            assert sorted(db.keyframe_data(sample)) == sorted(generate.CAMERA_CHANNELS + ("LIDAR_TOP",))
    instances = db.table("instance")
    counts = np.bincount(db.table("sample_annotation").rows("instance_token"), minlength=len(instances))
    np.testing.assert_array_equal(counts, instances.column("nbr_annotations"))


def test_scene_names_resolve_devkit_mini_splits(tiny_dataroot):
    names = sorted(NuScenesDB(tiny_dataroot, "v1.0-mini").table("scene").column("name"))
    assert names == ["scene-0061", "scene-0103"]  # mini_train and mini_val


def _lidar_chain(db, scene):
    """sample_data records of a scene's LIDAR_TOP, first keyframe to last, following next."""
    first_sample = db.sample_tokens_of_scene(scene)[0]
    record = db.get("sample_data", db.keyframe_data(first_sample)["LIDAR_TOP"])
    chain = [record]
    while record["next"]:
        following = db.get("sample_data", record["next"])
        assert following["prev"] == record["token"]
        chain.append(record := following)
    return chain


def test_lidar_sweeps_at_20_hz_chain_through_keyframes_as_in_nuscenes(tiny_dataroot):
    db = NuScenesDB(tiny_dataroot, "v1.0-mini")
    lidar_sensor = next(s.token for s in SENSORS if s.channel == "LIDAR_TOP")
    for scene in db.table("scene").tokens:
        samples = db.sample_tokens_of_scene(scene)
        chain = _lidar_chain(db, scene)
        assert chain[0]["prev"] == "" and len(chain) == 1 + 2 * 10
        key = [record["is_key_frame"] for record in chain]
        assert key == [True] + ([False] * 9 + [True]) * 2
        assert [r["token"] for r, k in zip(chain, key) if k] == [db.keyframe_data(s)["LIDAR_TOP"] for s in samples]
        np.testing.assert_array_equal(np.diff([r["timestamp"] for r in chain]), 50_000)
        for position, record in enumerate(chain):
            # A sweep belongs to the sample of the key frame that follows it.
            assert record["sample_token"] == samples[-(-position // 10)]
            folder = "samples" if record["is_key_frame"] else "sweeps"
            assert record["filename"].startswith(f"{folder}/LIDAR_TOP/") and record["filename"].endswith(
                f"__LIDAR_TOP__{record['timestamp']}.pcd.bin")
            assert db.get("ego_pose", record["ego_pose_token"])["timestamp"] == record["timestamp"]
            assert db.get("calibrated_sensor", record["calibrated_sensor_token"])["sensor_token"] == lidar_sensor
            assert 20_000 < len(db.read_lidar(record["token"])) < 40_000


def test_num_lidar_pts_counts_the_points_inside_each_box(tiny_dataroot):
    # num_lidar_pts repeats the devkit's float arithmetic (tests/test_devkit_crosscheck.py checks it
    # against the devkit itself); our global-frame geometry agrees up to points within 2 mm of a face.
    db = NuScenesDB(tiny_dataroot, "v1.0-mini")
    annotations = db.table("sample_annotation")
    for sample in db.table("sample").tokens:
        lidar = db.keyframe_data(sample)["LIDAR_TOP"]
        points = db.read_lidar(lidar)
        to_global = sensor_to_global(*db.ego_pose_of(lidar), *db.calibration_of(lidar)[:2])
        points_global = apply_transform(to_global, points[:, :3])
        rows = db.sample_annotation_rows(sample)
        center, size, rotation = (annotations.column(name)[rows] for name in ("translation", "size", "rotation"))
        stored = annotations.column("num_lidar_pts")[rows]
        assert np.all(count_points_in_boxes(points_global, center, size - 0.004, rotation) <= stored)
        assert np.all(count_points_in_boxes(points_global, center, size + 0.004, rotation) >= stored)


def test_every_track_starts_and_ends_on_a_sighting(tiny_dataroot):
    # The LiDAR sights objects: one point, two beyond SINGLE_POINT_SIGHTING_RANGE; radar returns
    # are counted but sight nothing. Boxes between the first and last sighting may hold nothing.
    db = NuScenesDB(tiny_dataroot, "v1.0-mini")
    annotations = db.table("sample_annotation")
    ego = {sample: db.ego_pose_of(db.keyframe_data(sample)["LIDAR_TOP"])[1][:2] for sample in db.table("sample").tokens}
    samples = annotations.column("sample_token")
    distance = np.hypot(*(annotations.column("translation")[:, :2] - np.stack([ego[t] for t in samples])).T)
    lidar, radar = annotations.column("num_lidar_pts"), annotations.column("num_radar_pts")
    sighted = lidar >= np.where(distance < generate.SINGLE_POINT_SIGHTING_RANGE, 1, 2)
    instances = db.table("instance")
    ends = np.concatenate([instances.rows("first_annotation_token"), instances.rows("last_annotation_token")])
    assert sighted[ends].all()
    assert (radar > 0).any()


def test_images_match_their_scaled_intrinsics(tiny_dataroot):
    db = NuScenesDB(tiny_dataroot, "v1.0-mini")
    sample = db.table("sample").tokens[0]
    token = db.keyframe_data(sample)["CAM_FRONT"]
    image = db.read_image(token)
    assert image.shape == (90, 160, 3)
    _, _, intrinsic = db.calibration_of(token)
    front_focals = {rig[0].focal for rig in (generate.RIG_BOSTON, generate.RIG_SINGAPORE)}
    assert min(abs(intrinsic[0, 0] - 0.1 * f) for f in front_focals) < 0.01  # calibrated fx, scaled 0.1


def test_same_seed_same_bytes_and_workers_do_not_matter(tmp_path, tiny_dataroot, make_tiny):
    again = make_tiny(tmp_path / "again")
    parallel = run(SynthConfig(scenes=2, image_scale=0.1, scene_seconds=1.5, seed=3), tmp_path / "parallel",
                   workers=2).out
    assert _digest(again) == _digest(tiny_dataroot)
    assert _digest(parallel) == _digest(tiny_dataroot)


def test_other_seed_other_world(tmp_path, tiny_dataroot, make_tiny):
    other = make_tiny(tmp_path / "other", seed=4)
    annotation_file = "v1.0-mini/sample_annotation.json"
    assert _digest(other)[annotation_file] != _digest(tiny_dataroot)[annotation_file]


def test_sensors_none_writes_the_same_annotations(tmp_path, make_tiny, tiny_dataroot):
    """Tables-only sets stand for the full data: the same boxes, point and radar counts,
    visibility and attributes (visibility is measured by the same coverage cast either way)."""
    root = make_tiny(tmp_path / "tables", sensors="none")
    assert not (root / "samples").exists() and not (root / "sweeps").exists()
    db = NuScenesDB(root, "v1.0-mini")
    assert db.table("sample_data").column("is_key_frame").all()  # no sweep records without their files
    tables_only = json.loads((root / "v1.0-mini" / "sample_annotation.json").read_text())
    full = json.loads((tiny_dataroot / "v1.0-mini" / "sample_annotation.json").read_text())
    assert tables_only == full
    assert sum(a["num_lidar_pts"] for a in full) > 0 and len({a["visibility_token"] for a in full}) > 1


def test_the_marker_records_what_wrote_the_dataroot(tiny_dataroot):
    marker = json.loads((tiny_dataroot / MARKER_NAME).read_text())
    assert marker["kind"] == "sianms synth dataroot" and marker["sianms_version"] == __version__
    assert marker["config"] == {"version": "v1.0-mini", "scenes": 2, "image_scale": 0.1, "seed": 3,
                                "sensors": "all", "scene_seconds": 1.5}
    assert marker["platform"] == numeric_platform() and marker["platform"]["numpy"] == np.__version__
    assert sorted(p.name for p in tiny_dataroot.iterdir()) == ["maps", "samples", MARKER_NAME, "sweeps", "v1.0-mini"]


def test_an_empty_folder_is_filled_and_a_non_empty_one_refused(tmp_path, make_tiny):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert (make_tiny(empty, scenes=1, sensors="none") / MARKER_NAME).is_file()
    with pytest.raises(OutputExistsError, match="exists and is not empty; pass --overwrite"):
        make_tiny(empty, scenes=1, sensors="none")


def test_overwrite_replaces_an_earlier_synth_output(tmp_path, make_tiny):
    out = make_tiny(tmp_path / "out", version="synth-v1", scenes=1, image_scale=0.1, scene_seconds=0.5)
    run(SynthConfig(scenes=1, image_scale=0.1, scene_seconds=0.5, seed=9), out, overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == ["maps", "samples", MARKER_NAME, "v1.0-mini"]
    assert json.loads((out / MARKER_NAME).read_text())["config"]["seed"] == 9
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # the old dataroot is gone, nothing beside


def _earlier_output(out, *extra):
    """A dataroot an earlier run wrote (marker, tables folder, samples), plus ``extra`` entries."""
    (out / "v1.0-mini").mkdir(parents=True)
    (out / "samples").mkdir()
    (out / MARKER_NAME).write_text(json.dumps({"kind": "sianms synth dataroot", "config": {"version": "v1.0-mini"}}))
    for name in extra:
        (out / name).write_text("mine")
    return out


@pytest.mark.parametrize("make_out, first_foreign", [
    (lambda out: _earlier_output(out, "keep.txt"), "'keep.txt' is not something sianms synth writes"),
    (lambda out: _earlier_output(out, "v1.0-trainval"), "'v1.0-trainval' is not something sianms synth writes"),
    (lambda out: (_earlier_output(out) / MARKER_NAME).write_text("{"), "no valid sianms-synth.json"),
    (lambda out: (_earlier_output(out) / MARKER_NAME).unlink(), "no valid sianms-synth.json.*'samples'"),
    (lambda out: (out.mkdir(), (out / "keep.txt").write_text("mine")), "no valid sianms-synth.json.*'keep.txt'"),
], ids=["foreign-file", "foreign-version", "bad-marker", "no-marker", "user-folder"])
def test_overwrite_never_replaces_a_folder_with_anything_else_in_it(tmp_path, make_out, first_foreign):
    out = tmp_path / "out"
    make_out(out)
    before = sorted(p.name for p in out.iterdir())
    with pytest.raises(OutputExistsError, match=f"{out}: not replaced: .*{first_foreign}"):
        run(SynthConfig(scenes=1, sensors="none", scene_seconds=0.5), out, overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == before
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


@pytest.mark.parametrize("placed, named", [
    ("samples/my_photos/a.jpg", "samples/my_photos"),
    ("samples/CAM_FRONT/notes.txt", "samples/CAM_FRONT/notes.txt"),
    ("samples/LIDAR_TOP/a.jpg", "samples/LIDAR_TOP/a.jpg"),
    ("maps/expansion/boston-seaport.json", "maps/expansion"),  # where the devkit's map expansion goes
    ("v1.0-mini/notes.txt", "v1.0-mini/notes.txt"),
    ("samples/CAM_FRONT/myphoto.jpg", "samples/CAM_FRONT/myphoto.jpg"),  # synth's suffix, not its name
    ("maps/myscan.png", "maps/myscan.png"),
    ("samples/CAM_BACK/n008-2018-08-01-15-16-36-0400__CAM_FRONT__1533151603512404.jpg",
     "samples/CAM_BACK/n008-2018-08-01-15-16-36-0400__CAM_FRONT__1533151603512404.jpg"),
])
def test_overwrite_looks_inside_synths_own_folders(tmp_path, placed, named):
    out = _earlier_output(tmp_path / "out")
    own_files = ("samples/CAM_FRONT/n008-2018-08-01-15-16-36-0400__CAM_FRONT__1533151603512404.jpg",
                 "samples/LIDAR_TOP/n015-2018-07-24-11-22-45+0800__LIDAR_TOP__1532402927647951.pcd.bin",
                 "maps/36092f0b03a857c6a3403e25b4b7aab3.png", "v1.0-mini/scene.json")
    for own in (*own_files, placed):
        (out / own).parent.mkdir(parents=True, exist_ok=True)
        (out / own).write_text("x")
    with pytest.raises(OutputExistsError, match=f"{out}: not replaced: '{named}' is not something sianms synth writes"):
        run(SynthConfig(scenes=1, sensors="none", scene_seconds=0.5), out, overwrite=True)
    assert (out / placed).read_text() == "x"


def test_a_linked_entry_is_never_synth_output(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    out = _earlier_output(tmp_path / "out")
    (out / "maps").symlink_to(elsewhere)
    with pytest.raises(OutputExistsError, match="'maps' is not something"):
        run(SynthConfig(scenes=1, sensors="none", scene_seconds=0.5), out, overwrite=True)


def test_refuses_an_output_that_is_a_file(tmp_path):
    (tmp_path / "out").write_text("mine")
    with pytest.raises(OutputExistsError, match="out: exists and is not a folder"):
        run(SynthConfig(scenes=1, sensors="none", scene_seconds=0.5), tmp_path / "out", overwrite=True)
    assert (tmp_path / "out").read_text() == "mine"


@pytest.mark.parametrize("out", [".", "..", ""])
def test_refuses_the_working_folder_and_its_parents(tmp_path, monkeypatch, out):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    with pytest.raises(SianmsError, match="is the working folder or one of its parents"):
        run(SynthConfig(scenes=1, sensors="none", scene_seconds=0.5), out, overwrite=True)
    assert [p.name for p in tmp_path.iterdir()] == ["work"] and list(work.iterdir()) == []


def test_an_interrupted_run_leaves_nothing(tmp_path, monkeypatch, make_tiny):
    def fail(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(generate, "_scene_records", fail)
    with pytest.raises(KeyboardInterrupt):
        make_tiny(tmp_path / "out", scenes=1)
    assert list(tmp_path.iterdir()) == []


def test_custom_version_writes_splits_json(tmp_path, make_tiny):
    root = make_tiny(tmp_path / "custom", version="synth-v1", scenes=3, sensors="none", scene_seconds=0.5)
    splits = json.loads((root / "synth-v1" / "splits.json").read_text())
    assert splits == {"synth_train": ["scene-0001", "scene-0002"], "synth_val": ["scene-0003"]}


def test_trainval_names_come_from_the_devkit_train_and_val_lists():
    from sianms_cli.nuscenes.splits import splits_for_version

    official = splits_for_version("v1.0-trainval")
    names = scene_names_for("v1.0-trainval", 12)
    val = [n for n in names if n in official["val"]]
    assert len(names) == 12 and len(val) == 2  # 150/850 of 12, rounded
    assert set(names) - set(val) <= set(official["train"])


@pytest.mark.parametrize("options, message", [
    (dict(scenes=0), "--scenes must be at least 1"),
    (dict(scenes=11), "has 10 scenes"),
    (dict(version="v1.0-trainval"), "--scenes is required"),
    (dict(version="v1.0-trainval", scenes=851), r"v1.0-trainval has 850 scenes \(700 train, 150 val\); --scenes 851"),
    (dict(version="v1.0-test", scenes=151), r"v1.0-test has 150 scenes \(150 test\); --scenes 151 asks for more"),
    (dict(version="v2-custom", scenes=10**12), r"^--scenes must be at most 10,000 for version v2-custom, got 10+$"),
    (dict(scenes=1, image_scale=0.0), "--image-scale"),
    (dict(scenes=1, image_scale=float("nan")), "--image-scale"),
    (dict(scenes=1, sensors="radar"), "--sensors must be one of"),
    (dict(scenes=1, scene_seconds=25), "--scene-seconds"),
    (dict(scenes=1, scene_seconds=0.2), "--scene-seconds .* at least one keyframe"),
    (dict(scenes=1, seed=-1), r"--seed must be between 0 and 2\*\*63 - 1, got -1"),
    (dict(scenes=1, version="../escape"), "--version must be one folder name"),
    (dict(scenes=1, version="v1.0-mini/.."), "--version must be one folder name"),
])
def test_bad_options_fail_when_the_config_is_built(options, message):
    with pytest.raises(SianmsError, match=message):
        SynthConfig(**options)


def test_bad_worker_count_fails_before_anything_is_written(tmp_path):
    with pytest.raises(SianmsError, match="--workers must be at least 1"):
        run(SynthConfig(scenes=1), tmp_path / "out", workers=0)
    assert list(tmp_path.iterdir()) == []


def test_scene_descriptions_say_what_the_ego_does_and_where():
    from sianms_cli.synth.world import plan_scene

    texts = {seed: generate._describe(plan_scene(np.random.default_rng(seed), drive_side=+1 if seed % 2 else -1),
                                      "boston-seaport") for seed in (26, 3, 4, 36)}
    assert "Three lanes each way, median" in texts[26] and "ego changes lane" in texts[26]
    assert "lane changes and parking manoeuvres" in texts[26] and "turning traffic" in texts[26]
    assert "ego turns" in texts[3] and "T junction" in texts[3]
    assert "4-way junction" in texts[36]
    assert "car park" in texts[4] and "roadworks" in texts[4]
    assert all(text.endswith("Boston") for text in texts.values())
