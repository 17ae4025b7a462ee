"""data/multiview.py: the union training frustums of `sianms train fpointnet --multiview`, checked
against the pair geometry of `sianms eval` (evaluation/multiview.py) on the tiny mini's cache."""

import json
import shutil

import numpy as np
import pyarrow.parquet as pq
import pytest

from sianms_cli.data.frustum_dataset import FrustumSelection, iterate_batches, read_shard
from sianms_cli.data.multiview import build_union_shards, multiview_settings, union_frustums
from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.geometry.boxes import points_in_boxes
from sianms_cli.geometry.frustum import rotate_to_frustum
from sianms_cli.geometry.transforms import sensor_to_global
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.evaluation.multiview import pair_geometry, pair_union
from sianms_cli.prepare.sample import lidar_points_global, scene_records

ALL = FrustumSelection(min_box_height=0)


@pytest.fixture(scope="module")
def inputs(tiny_caches, synthetic_dataroot):
    cache = tiny_caches[0]
    shard = sorted((cache / "pairs").glob("*.parquet"))[0].stem
    return cache, synthetic_dataroot(), shard


@pytest.fixture(scope="module")
def db(inputs):
    return NuScenesDB(inputs[1], "v1.0-mini")


def _frame(records, position, channel):
    keyframes, c = records.keyframes, records.channels.index(channel)
    return (sensor_to_global(keyframes.ego_rotation[position, c], keyframes.ego_translation[position, c],
                             keyframes.sensor_rotation[position, c], keyframes.sensor_translation[position, c]),
            keyframes.intrinsic[position, c])


def _pair_by_hand(db, cache, pair, max_distance):
    """One pairs/ row's union frustum, straight from evaluation/multiview.py: (overlap, inside, union
    points in the union frame, points in camera_a's frame, angle, GT box row of the reference)."""
    detections = pq.read_table(next((cache / "detections").glob("*.parquet"))).to_pandas().set_index("detection_id")
    boxes = pq.read_table(next((cache / "frustums").glob("*.parquet"))).to_pandas().set_index("detection_id")
    records = scene_records(db, pair["scene_token"], 0)
    position = records.position(pair["sample_token"])
    frame_a, frame_b = _frame(records, position, pair["camera_a"]), _frame(records, position, pair["camera_b"])
    box2d = np.array([detections.loc[pair[key], ["x1", "y1", "x2", "y2"]].to_numpy(dtype=np.float64)
                      for key in ("reference_detection_id", "positive_detection_id")])
    geometry = pair_geometry(box2d[:1], box2d[1:], frame_a[0][None], frame_b[0][None], frame_a[1][None],
                             frame_b[1][None], max_distance)
    points, extra = lidar_points_global(db, records, position)
    inside, union = pair_union(points, geometry, 0, box2d, (frame_a[1], frame_b[1]), 1.0, np.inf)
    to_a = np.linalg.inv(frame_a[0])
    points_a = points[inside] @ to_a[:3, :3].T + to_a[:3, 3]
    return bool(geometry.overlap[0]), inside, union, points_a, extra[inside, 0], float(geometry.angle[0]), \
        boxes.loc[pair["reference_detection_id"]]


@pytest.fixture(scope="module")
def unions(inputs, db):
    cache, root, shard = inputs
    return union_frustums(db, cache, shard, ALL, multiview_settings(cache, str(root), 50.0)).to_pandas()


def test_union_labels_are_the_union_points_inside_the_gt_box(inputs, db, unions):
    cache, _, _ = inputs
    pairs = pq.read_table(next((cache / "pairs").glob("*.parquet"))).to_pandas()
    assert len(unions) >= 3
    for row in unions.itertuples():
        pair = pairs[(pairs.reference_detection_id == row.detection_id)
                     & (pairs.positive_detection_id == row.positive_detection_id)].iloc[0]
        overlap, inside, union, points_a, intensity, angle, box = _pair_by_hand(db, cache, pair, 50.0)
        assert overlap and row.num_points == inside.sum()
        assert np.array_equal(np.stack([row.x, row.y, row.z], axis=1), union.astype(np.float32))
        assert np.array_equal(row.intensity, intensity.astype(np.float32))  # raw 0-255, as the cache's
        expected = points_in_boxes(points_a, np.asarray(box.box_center_cam)[None], np.asarray(box.box_size)[None],
                                   np.asarray(box.box_rotation_cam)[None])[0]
        assert np.array_equal(row.label, expected.astype(np.int8)) and expected.any()
        assert row.rot_angle == np.float32(angle)


def test_union_centre_and_heading_round_trip_to_the_gt_box_in_camera_a(unions):
    for row in unions.itertuples():
        center = rotate_to_frustum(np.asarray(row.box_center_frustum, dtype=np.float64)[None], -row.rot_angle)[0]
        assert center == pytest.approx(np.asarray(row.box_center_cam), abs=1e-4)
        assert row.box_heading_frustum + row.rot_angle == pytest.approx(row.box_heading_cam, abs=1e-5)
        # in the union frame the labelled points are the points inside (centre, l w h, heading),
        # F-PointNets' convention (length axis (cos h, 0, -sin h)), but for points near a face: the
        # yaw-only box ignores the camera's tilt to the box's up axis (about 1°: the rig's pitch and
        # roll), which moves a point at distance r from the centre by up to r sin(1.5°), plus 1 cm
        # (the single frustums of the cache differ from it so too)
        points = np.stack([row.x, row.y, row.z], axis=1) - np.asarray(row.box_center_frustum)
        w, length, h = row.box_size
        c, s = np.cos(row.box_heading_frustum), np.sin(row.box_heading_frustum)
        along, across = points[:, 0] * c - points[:, 2] * s, points[:, 0] * s + points[:, 2] * c
        margin = np.minimum.reduce([length / 2 - np.abs(along), w / 2 - np.abs(across), h / 2 - np.abs(points[:, 1])])
        clear = np.abs(margin) > 0.01 + np.linalg.norm(points, axis=1) * np.sin(np.radians(1.5))
        assert np.array_equal(row.label[clear] == 1, margin[clear] > 0)


def test_multiview_adds_exactly_the_overlapping_pairs(inputs, db, tmp_path):
    """At a 5 m circle some wedges do not overlap: exactly the pairs that do (with an object point in
    the union) are added, in pairs/ order; at 50 m every pair of the cache overlaps, and all but
    the pairs whose object left no LiDAR point in the union (hidden in both views) are added."""
    cache, root, shard = inputs
    pairs = pq.read_table(cache / "pairs" / f"{shard}.parquet").to_pandas()
    for max_distance in (5.0, 50.0):
        expected, overlapping = [], 0
        for _, pair in pairs.iterrows():
            overlap, inside, _, points_a, _, _, box = _pair_by_hand(db, cache, pair, max_distance)
            labels = points_in_boxes(points_a, np.asarray(box.box_center_cam)[None], np.asarray(box.box_size)[None],
                                     np.asarray(box.box_rotation_cam)[None])[0] if inside.any() else inside[:0]
            overlapping += bool(overlap)
            if overlap and labels.any():
                expected.append((pair.reference_detection_id, pair.positive_detection_id))
        folder = tmp_path / f"unions-{max_distance}"
        counts = build_union_shards(cache, folder, ALL, multiview_settings(cache, str(root), max_distance))
        table = pq.read_table(folder / f"{shard}.parquet")
        assert list(zip(table["detection_id"].to_pylist(), table["positive_detection_id"].to_pylist())) == expected
        assert counts == {f"{shard}.parquet": len(expected)}
        if max_distance == 5.0:
            assert 0 < len(expected) < len(pairs)
        else:
            assert overlapping == len(pairs) and len(expected) >= len(pairs) - 2
    # and the training stream carries them beside the single frustums, flagged
    batches = list(iterate_batches(cache, ALL, 4, np.random.default_rng(0), train=False, unions=folder))
    flags = np.concatenate([batch["union"] for batch in batches])
    assert flags.sum() == len(expected)
    assert (~flags).sum() == len(read_shard(cache / "frustums" / f"{shard}.parquet", ALL))


def test_union_files_are_reused_and_rebuilt_when_their_inputs_change(inputs, tmp_path):
    cache, root, shard = inputs
    target = tmp_path / "unions" / f"{shard}.parquet"
    build_union_shards(cache, tmp_path / "unions", ALL, multiview_settings(cache, str(root), 50.0))
    made = target.stat().st_mtime_ns
    assert "car" in pq.read_table(target)["class"].to_pylist()
    build_union_shards(cache, tmp_path / "unions", ALL, multiview_settings(cache, str(root), 50.0))
    assert target.stat().st_mtime_ns == made  # same key: not recomputed
    build_union_shards(cache, tmp_path / "unions", FrustumSelection(classes=("pedestrian",), min_box_height=0),
                       multiview_settings(cache, str(root), 50.0))
    assert set(pq.read_table(target)["class"].to_pylist()) <= {"pedestrian"}  # other classes: rebuilt


def test_a_dataroot_of_another_dataset_is_refused(inputs, tmp_path):
    cache, root, _ = inputs
    other = tmp_path / "other"
    shutil.copytree(root / "v1.0-mini", other / "v1.0-mini")
    for folder in ("samples", "sweeps", "maps"):
        (other / folder).symlink_to(root / folder)
    log = other / "v1.0-mini" / "log.json"
    log.write_text(json.dumps(json.loads(log.read_text()), indent=3))  # same records, other bytes
    with pytest.raises(SianmsError, match="--dataroot"):
        build_union_shards(cache, tmp_path / "unions", ALL, multiview_settings(cache, str(other), 50.0))
    # and when every union file is there already (a resume): its config would record the other dataset
    build_union_shards(cache, tmp_path / "unions", ALL, multiview_settings(cache, str(root), 50.0))
    with pytest.raises(SianmsError, match="--dataroot .*: not the dataset the cache"):
        build_union_shards(cache, tmp_path / "unions", ALL, multiview_settings(cache, str(other), 50.0))
    with pytest.raises(DataFormatError, match="version folder not found"):
        build_union_shards(cache, tmp_path / "unions", ALL, multiview_settings(cache, str(tmp_path / "none"), 50.0))


@pytest.mark.parametrize("name, value, expected", [
    ("sweeps", "x", "a whole number in [0, 100]"),
    ("min_depth", None, "a finite number >= 0"),
    ("max_depth", "far", "null or a finite number above min_depth"),
    ("max_depth", 0.5, "null or a finite number above min_depth"),
])
def test_an_edited_lidar_setting_of_the_manifest_is_named(inputs, tmp_path, name, value, expected):
    """Each had ended in a ValueError or TypeError traceback when union frustums were set up."""
    cache, root, _ = inputs
    edited = shutil.copytree(cache, tmp_path / "cache")
    manifest = json.loads((edited / "manifest.json").read_text())
    manifest["config"][name] = value
    (edited / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DataFormatError) as raised:
        multiview_settings(edited, str(root), 50.0)
    assert str(raised.value) == f"{edited / 'manifest.json'}: field 'config.{name}': expected {expected}, got {value!r}"
