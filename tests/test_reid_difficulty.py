"""bench/reid_difficulty.py on a hand-made two-camera dataset and cache whose answers are known.

One sample, CAM_FRONT and CAM_FRONT_RIGHT 45 degrees apart (320 x 180 images, 65 degree field of
view: each sees the other's overlap strip at one side), painted boxes in flat colours on grey,
aligned to JPEG blocks and saved 4:4:4 so equal paint decodes to equal pixels. Ground-truth cars:

- A: in both cameras, 64 px tall, red; in both strips;
- B: CAM_FRONT_RIGHT only, 64 px, in its strip; red or blue (the test's choice);
- E: in both, 16 px tall (too small to ask), its CAM_FRONT_RIGHT box in the strip;
- G: in both, 48 px tall, outside both strips (left out);
- a pedestrian in CAM_FRONT's strip (not a car: never a candidate).

So CAM_FRONT -> CAM_FRONT_RIGHT asks A among {A, B, E}; CAM_FRONT_RIGHT -> CAM_FRONT asks A
among {A} alone.
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from cache_records import record_again
from PIL import Image

from sianms_cli.data.schemas import SCHEMA_VERSION, cache_schemas
from sianms_cli.errors import DataFormatError
from sianms_cli.geometry.quaternion import quat_multiply, yaw_to_quat
from sianms_cli.nuscenes.tables import SENSORS
from sianms_cli.nuscenes.writer import DatasetWriter, make_token

BENCH = Path(__file__).resolve().parents[1] / "bench" / "reid_difficulty.py"
spec = importlib.util.spec_from_file_location("reid_difficulty", BENCH)
reid = sys.modules["reid_difficulty"] = importlib.util.module_from_spec(spec)  # dataclasses look their module up
spec.loader.exec_module(reid)

VERSION = "v1.0-mini"
WIDTH, HEIGHT, FOCAL = 320, 180, 253.3
CAMERA_YAW = {"CAM_FRONT": 0.0, "CAM_FRONT_RIGHT": -np.pi / 4}
FORWARD_CAMERA = np.array([0.5, -0.5, 0.5, -0.5])  # camera z along ego x, camera x along ego -y
SENSOR_TOKEN = {sensor.channel: sensor.token for sensor in SENSORS}
FEATURE_SHAPE = (8, 7, 7)
RED, BLUE, GREY = (200, 30, 30), (30, 30, 200), (128, 128, 128)
# (camera, instance, class, box [x1, y1, x2, y2], colour)
BOXES = [
    ("CAM_FRONT", "A", "car", (240, 48, 288, 112), RED),
    ("CAM_FRONT", "P", "pedestrian", (288, 48, 304, 112), (30, 200, 30)),
    ("CAM_FRONT", "E", "car", (160, 16, 176, 32), (250, 250, 250)),
    ("CAM_FRONT", "G", "car", (128, 120, 160, 168), (200, 200, 30)),
    ("CAM_FRONT_RIGHT", "A", "car", (16, 48, 48, 112), RED),
    ("CAM_FRONT_RIGHT", "B", "car", (64, 48, 96, 112), "b"),
    ("CAM_FRONT_RIGHT", "E", "car", (0, 16, 16, 32), (250, 250, 250)),
    ("CAM_FRONT_RIGHT", "G", "car", (208, 120, 240, 168), (200, 200, 30)),
]


def write_dataset(root: Path, colour_b: tuple[int, int, int]) -> dict[str, str]:
    """The tables and JPEGs of the one-sample dataset; {channel: key-frame sample_data token}."""
    scene, sample, log = make_token("scene", 0), make_token("sample", 0), make_token("log", 0)
    tokens = {}
    with DatasetWriter(root, VERSION) as writer:
        writer.add_static_tables()
        writer.add("log", {"token": log, "logfile": "handmade", "vehicle": "n0", "date_captured": "2018-07-24",
                           "location": "boston-seaport"})
        writer.add_map(make_token("map", 0), [log])
        writer.add("scene", {"token": scene, "log_token": log, "nbr_samples": 1, "first_sample_token": sample,
                             "last_sample_token": sample, "name": "scene-0001", "description": "hand-made"})
        writer.add("sample", {"token": sample, "timestamp": 1_000_000, "prev": "", "next": "", "scene_token": scene})
        for channel, yaw in CAMERA_YAW.items():
            token = tokens[channel] = make_token("sample_data", channel)
            writer.add("calibrated_sensor", {
                "token": make_token("calibrated_sensor", channel), "sensor_token": SENSOR_TOKEN[channel],
                "translation": [1.5, 0.0, 1.5], "rotation": quat_multiply(yaw_to_quat(yaw), FORWARD_CAMERA).tolist(),
                "camera_intrinsic": [[FOCAL, 0, WIDTH / 2], [0, FOCAL, HEIGHT / 2], [0, 0, 1]]})
            writer.add("ego_pose", {"token": token, "timestamp": 1_000_000, "rotation": [1.0, 0, 0, 0],
                                    "translation": [0.0, 0.0, 0.0]})
            filename = f"samples/{channel}/handmade__{channel}__1000000.jpg"
            writer.add("sample_data", {
                "token": token, "sample_token": sample, "ego_pose_token": token,
                "calibrated_sensor_token": make_token("calibrated_sensor", channel), "timestamp": 1_000_000,
                "fileformat": "jpg", "is_key_frame": True, "height": HEIGHT, "width": WIDTH, "filename": filename,
                "prev": "", "next": ""})
            image = np.full((HEIGHT, WIDTH, 3), GREY, dtype=np.uint8)
            for camera, _, _, (x1, y1, x2, y2), colour in BOXES:
                if camera == channel:
                    image[y1:y2, x1:x2] = colour_b if colour == "b" else colour
            (root / filename).parent.mkdir(parents=True, exist_ok=True)
            Image.fromarray(image).save(root / filename, quality=95, subsampling=0)
    return tokens


def write_cache(cache: Path, dataroot: Path, tokens: dict[str, str], features: np.ndarray) -> None:
    """A one-shard cache of BOXES: manifest and detections (``features``: (len(BOXES), C, 7, 7))."""
    schema = cache_schemas(FEATURE_SHAPE, "tiny")["detections"]
    rows = {name: [] for name in schema.names}
    for index, (camera, instance, name, box, _) in enumerate(BOXES):
        values = {
            "detection_id": f"{tokens[camera]}_{index}", "scene_token": make_token("scene", 0),
            "sample_token": make_token("sample", 0), "sample_data_token": tokens[camera], "camera": camera,
            "scene_name": "scene-0001", "detection_index": index, "x1": box[0], "y1": box[1], "x2": box[2],
            "y2": box[3], "score": 0.9, "class": name, "source": "detector", "image_width": WIDTH,
            "image_height": HEIGHT, "instance_token": make_token("instance", instance),
            "annotation_token": make_token("sample_annotation", instance), "iou": 0.9, "gt_truncation": 0.0,
            "gt_occlusion": 0.0, "gt_distance": 10.0, "overlap_pairs": [],
            "roi_feature": features[index].astype("<f2").tobytes()}
        for key, value in values.items():
            rows[key].append(value)
    (cache / "detections").mkdir(parents=True)
    pq.write_table(pa.table(rows, schema=schema), cache / "detections" / "scene-0001.parquet")
    (cache / "manifest.json").write_text(json.dumps({
        "schema_version": SCHEMA_VERSION, "config": {"version": VERSION}, "dataroot": str(dataroot)}))
    record_again(cache)  # complete, listing the shard as prepare would


@pytest.fixture
def handmade(tmp_path):
    """``make(colour_b, features=None)``: (cache, dataroot) of the hand-made dataset."""

    def make(colour_b, features=None):
        folder = tmp_path / f"b{len(list(tmp_path.iterdir()))}"
        dataroot, cache = folder / "data", folder / "cache"
        tokens = write_dataset(dataroot, colour_b)
        if features is None:
            features = np.zeros((len(BOXES), *FEATURE_SHAPE))
        write_cache(cache, dataroot, tokens, features)
        return cache, dataroot

    return make


def test_distinct_colours_pick_the_right_car(handmade):
    cache, _ = handmade(BLUE)
    result = reid.difficulty(cache)
    assert result["queries"] == 2 and result["queries_with_choice"] == 1
    assert result["queries_by_pair"] == {"CAM_FRONT>CAM_FRONT_RIGHT": 1, "CAM_FRONT_RIGHT>CAM_FRONT": 1}
    assert result["outside_strip"] == 2  # G, both ways
    assert result["one_candidate_share"] == 0.5
    assert result["mean_candidates"] == 2.0 and result["mean_candidates_with_choice"] == 3.0
    assert result["chance"] == pytest.approx(1 / 3)
    for name in ("mean colour (sRGB)", "mean colour (CIELAB)"):
        assert result["matchers"][name] == {"top1": 1.0, "tie_share": 0.0}
    # A candidate height floor drops E: A among {A, B}.
    assert reid.difficulty(cache, candidate_min_height=40)["mean_candidates_with_choice"] == 2.0


def test_identical_colours_tie_and_earn_one_over_k(handmade):
    cache, _ = handmade(RED)
    result = reid.difficulty(cache)
    assert result["matchers"]["mean colour (sRGB)"] == {"top1": 0.5, "tie_share": 1.0}


def test_queries_and_candidates_follow_the_strip_and_the_height_floor(handmade):
    cache, dataroot = handmade(BLUE)
    from sianms_cli.nuscenes.loader import NuScenesDB

    detections = reid.load_detections(cache)
    queries = reid.build_queries(detections, NuScenesDB(dataroot, VERSION))
    names = [f"{BOXES[d][0]}:{BOXES[d][1]}" for d in queries.detection]
    assert sorted(zip(queries.pair.tolist(), names)) == [
        ("CAM_FRONT>CAM_FRONT_RIGHT", "CAM_FRONT:A"), ("CAM_FRONT_RIGHT>CAM_FRONT", "CAM_FRONT_RIGHT:A")]
    front = int(np.flatnonzero(queries.pair == "CAM_FRONT>CAM_FRONT_RIGHT")[0])
    mine = queries.candidate_detection[queries.candidate_query == front]
    assert sorted(BOXES[d][1] for d in mine) == ["A", "B", "E"]
    # Raising the query floor above A's 64 px leaves no query.
    assert len(reid.build_queries(detections, NuScenesDB(dataroot, VERSION), min_height=65)) == 0


def test_siamese_uses_the_encoders_embedding_distance(handmade, tmp_path):
    torch = pytest.importorskip("torch")
    from sianms_cli.training.run import Checkpoint, save_checkpoint
    from sianms_cli.training.siamese import build_model

    config = {"dim": 8, "conv_channels": [8, 8], "hidden": [16], "standardize": False}
    torch.manual_seed(0)
    model = build_model(config, FEATURE_SHAPE)
    save_checkpoint(tmp_path / "checkpoint.pt", Checkpoint(kind="siamese", config=config, epoch=1,
                                                           model=model.state_dict(),
                                                           extra={"dis_thr": 1.0, "feature_shape": FEATURE_SHAPE}))
    features = np.random.default_rng(0).normal(size=(len(BOXES), *FEATURE_SHAPE))
    features[4] = features[0]  # A's two crops have identical features: distance 0
    cache, _ = handmade(RED, features)
    result = reid.difficulty(cache, checkpoint=str(tmp_path / "checkpoint.pt"))
    assert result["matchers"]["siamese (embedding L2)"] == {"top1": 1.0, "tie_share": 0.0}
    features[5] = features[0]  # B's too: A and B tie at distance 0 (E's differ)
    cache, _ = handmade(RED, features)
    result = reid.difficulty(cache, checkpoint=str(tmp_path / "checkpoint.pt"))
    assert result["matchers"]["siamese (embedding L2)"] == {"top1": 0.5, "tie_share": 1.0}


def test_main_prints_the_table_writes_json_and_never_imports_torch(handmade, tmp_path):
    cache, _ = handmade(BLUE)
    out = tmp_path / "reid.json"
    script = ("import runpy, sys\n"
              f"sys.argv = ['reid_difficulty.py', {str(cache)!r}, '--json', {str(out)!r}]\n"
              "try:\n"
              f"    runpy.run_path({str(BENCH)!r}, run_name='__main__')\n"
              "except SystemExit as done:\n"
              "    assert done.code == 0, done.code\n"
              "assert 'torch' not in sys.modules, 'torch was imported'\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "mean colour (sRGB)" in done.stdout and "100.0 %" in done.stdout
    written = json.loads(out.read_text())
    assert written["config"]["min_height"] == 40.0 and written["matchers"]["mean colour (sRGB)"]["top1"] == 1.0


def test_a_moved_dataroot_is_one_clear_error(handmade, tmp_path):
    cache, _ = handmade(BLUE)
    with pytest.raises(DataFormatError, match="version folder not found"):
        reid.difficulty(cache, dataroot=str(tmp_path / "elsewhere"))
    assert reid.main([str(tmp_path / "no-cache")]) == 2


def test_box_means_equal_a_slow_reference_on_fractional_boxes():
    rng = np.random.default_rng(1)
    image = rng.integers(0, 256, (20, 30, 3), dtype=np.uint8)
    boxes = np.array([[0.0, 0.0, 30.0, 20.0], [2.4, 3.6, 9.5, 7.49], [2.5, 0.5, 4.5, 1.5],  # edges on centres
                      [-5.0, 18.2, 3.1, 40.0], [10.2, 5.0, 10.3, 5.1]])  # clipped; holds no centre
    expected = []
    for x1, y1, x2, y2 in boxes:
        # Pixels whose centre (u + 0.5, v + 0.5) lies in the box, else the first one past its edge.
        u = [k for k in range(30) if x1 <= k + 0.5 < x2] or [min(k for k in range(30) if k + 0.5 >= x1)]
        v = [k for k in range(20) if y1 <= k + 0.5 < y2] or [min(k for k in range(20) if k + 0.5 >= y1)]
        expected.append(image[v[0]:v[-1] + 1, u[0]:u[-1] + 1].reshape(-1, 3).mean(0))
    np.testing.assert_allclose(reid.box_mean_colours(image, boxes), expected)


def test_lab_of_reference_colours():
    lab = reid.srgb_to_lab(np.array([[255, 255, 255], [0, 0, 0], [255, 0, 0]]))
    np.testing.assert_allclose(lab[0], [100, 0, 0], atol=1e-3)
    np.testing.assert_allclose(lab[1], [0, 0, 0], atol=1e-9)
    np.testing.assert_allclose(lab[2], [53.24, 80.09, 67.20], atol=0.01)  # sRGB red, CIE D65


def test_equal_key_pairs_match_a_brute_force_join():
    rng = np.random.default_rng(2)
    left, right = rng.integers(0, 5, 17), rng.integers(0, 5, 23)
    i, j = reid._equal_key_pairs(left, right)
    assert list(zip(i.tolist(), j.tolist())) == [(a, b) for a in range(17) for b in range(23) if left[a] == right[b]]
