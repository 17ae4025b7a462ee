from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from sianms_cli.data.cache import ShardWriter, clear_shard, decode_roi_features, shard_done, write_manifest
from sianms_cli.data.frustums import Frustum, extract_frustums, heading_in_camera
from sianms_cli.data.pairs import contiguous_pairs
from sianms_cli.data.schemas import FRUSTUMS_SCHEMA, PAIRS_SCHEMA, cache_schemas, detections_schema, with_metadata
from sianms_cli.geometry.boxes import box_corners, points_in_boxes
from sianms_cli.geometry.frustum import frustum_angle, points_in_frustum, rotate_to_frustum
from sianms_cli.geometry.quaternion import quat_multiply, yaw_to_quat

K = np.array([[100.0, 0, 50], [0, 100, 50], [0, 0, 1]])


def extract_frustum(
    points_cam: np.ndarray,
    extra: np.ndarray,
    box2d: np.ndarray,
    intrinsic: np.ndarray,
    gt_center_cam: np.ndarray | None = None,
    gt_size: np.ndarray | None = None,
    gt_rotation_cam: np.ndarray | None = None,
    min_depth: float = 1.0,
    max_depth: float = np.inf,
) -> Frustum:
    """The frustum of one 2D box: the slow, obviously-correct reference of ``extract_frustums``.

    Args:
        points_cam: (P, 3) LiDAR points in the camera frame.
        extra: (P, k) channels kept with each point.
        box2d: (4,) [x1, y1, x2, y2] pixels (bounds inclusive).
        intrinsic: (3, 3) camera matrix.
        gt_center_cam, gt_size, gt_rotation_cam: the associated box (3,), (3,), (4,), or None.
        min_depth, max_depth: depth window (exclusive), metres.
    """
    inside = points_in_frustum(points_cam, box2d, intrinsic, min_depth=min_depth, max_depth=max_depth)
    angle = float(frustum_angle(np.asarray(box2d).reshape(1, 4), intrinsic)[0])
    chosen = np.asarray(points_cam, dtype=np.float64)[inside]
    rotated = rotate_to_frustum(chosen, angle)
    labels = np.zeros(len(chosen), dtype=np.int8)
    box = None
    if gt_center_cam is not None:
        center = np.asarray(gt_center_cam, dtype=np.float64).reshape(1, 3)
        size = np.asarray(gt_size, dtype=np.float64).reshape(1, 3)
        rotation = np.asarray(gt_rotation_cam, dtype=np.float64).reshape(1, 4)
        if len(chosen):
            labels = points_in_boxes(chosen, center, size, rotation)[0].astype(np.int8)
        heading = float(heading_in_camera(rotation)[0])
        box = {
            "center_cam": center[0],
            "size": size[0],
            "rotation_cam": rotation[0],
            "heading_cam": heading,
            "center_frustum": rotate_to_frustum(center, angle)[0],
            "heading_frustum": heading - angle,
        }
    return Frustum(angle, rotated, np.asarray(extra)[inside], labels, box)


def test_frustum_keeps_points_in_the_box_rotates_and_labels():
    points = np.array([[0.0, 0, 10], [0.4, 0, 10], [3, 0, 10], [0, 0, 0.5], [0.1, 0.1, 20]])
    extra = np.arange(10, dtype=float).reshape(5, 2)
    box2d = np.array([45.0, 45, 55, 55])
    frustum = extract_frustum(points, extra, box2d, K, np.array([0, 0, 10.0]), np.array([1.0, 1, 1]),
                              np.array([1.0, 0, 0, 0]))
    # Points 0, 1, 4 project inside; point 3 is closer than 1 m; point 2 is outside.
    assert frustum.extra[:, 0].tolist() == [0, 2, 8]
    assert frustum.labels.tolist() == [1, 1, 0]
    assert frustum.rot_angle == pytest.approx(0.0)
    assert frustum.box["center_frustum"].tolist() == pytest.approx([0, 0, 10])
    # An off-centre box: its centre ray maps onto +z.
    off = extract_frustum(points, extra, np.array([75.0, 45, 85, 55]), K)
    ray = np.array([[0.3, 0.0, 1.0]])
    from sianms_cli.geometry.frustum import rotate_to_frustum
    assert rotate_to_frustum(ray, off.rot_angle)[0, 0] == pytest.approx(0.0, abs=1e-12)
    assert off.box is None and off.labels.sum() == 0


def test_heading_convention_of_frustum_pointnets():
    # Identity quaternion: the length axis is camera +x -> ry = 0; rotated 90 deg about camera y
    # so that it points along -z -> ry = pi/2 (ry = atan2(-v_z, v_x)).
    quarter = [np.cos(np.pi / 4), 0, np.sin(np.pi / 4), 0]  # +x -> -z
    assert heading_in_camera(np.array([[1.0, 0, 0, 0], quarter])).tolist() == pytest.approx([0.0, np.pi / 2])


def random_frustum_inputs(rng, boxes):
    """Points, 2D boxes and associated 3D boxes of one camera, with points on the boxes' corners and faces."""
    center = np.stack([rng.normal(0, 4, boxes), rng.normal(0, 1, boxes), rng.uniform(2, 45, boxes)], axis=1)
    size = rng.uniform(0.5, 5, (boxes, 3))
    tilt = np.concatenate([np.ones((boxes, 1)), rng.normal(0, 0.1, (boxes, 3))], axis=1)
    rotation = quat_multiply(yaw_to_quat(rng.uniform(-np.pi, np.pi, boxes)), tilt)
    corners = box_corners(center, size, rotation)
    on_faces = np.concatenate([corners, 0.5 * (corners[:, [0, 1, 4, 2]] + corners[:, [2, 3, 6, 7]])], axis=1)
    scattered = np.stack([rng.normal(0, 8, 3000), rng.normal(0, 2, 3000), rng.uniform(-5, 60, 3000)], axis=1)
    points = np.concatenate([on_faces.reshape(-1, 3), scattered])
    u = rng.uniform(-40, 240, boxes)
    v = rng.uniform(-20, 120, boxes)
    boxes2d = np.stack([u, v, u + rng.uniform(1, 90, boxes), v + rng.uniform(1, 60, boxes)], axis=1)
    return points, rng.random((len(points), 2)), boxes2d, center, size, rotation, rng.random(boxes) < 0.7


@pytest.mark.parametrize("seed", range(8))
def test_frustums_of_all_boxes_equal_the_one_box_reference_exactly(seed):
    rng = np.random.default_rng(seed)
    points, extra, boxes2d, center, size, rotation, has_box = random_frustum_inputs(rng, int(rng.integers(0, 25)))
    max_depth = (np.inf, 30.0)[seed % 2]
    batch = extract_frustums(points, extra, boxes2d, K, center, size, rotation, has_box, 1.0, max_depth)
    assert len(batch) == len(boxes2d) and batch.offsets[-1] == len(batch.points)
    for n in range(len(boxes2d)):
        box = (center[n], size[n], rotation[n]) if has_box[n] else (None, None, None)
        one = extract_frustum(points, extra, boxes2d[n], K, *box, 1.0, max_depth)
        rows = slice(batch.offsets[n], batch.offsets[n + 1])
        assert batch.rot_angle[n] == one.rot_angle
        assert np.array_equal(batch.points[rows], one.points) and np.array_equal(batch.extra[rows], one.extra)
        assert np.array_equal(batch.labels[rows], one.labels) and batch.labels.dtype == np.int8
        assert batch.has_box[n] == (one.box is not None)
        if one.box is None:
            assert np.isnan(batch.box_center_cam[n]).all() and np.isnan(batch.box_heading_frustum[n])
            continue
        for name in ("center_cam", "size", "rotation_cam", "center_frustum"):
            assert np.array_equal(getattr(batch, f"box_{name}")[n], one.box[name]), name
        assert batch.box_heading_cam[n] == one.box["heading_cam"]
        assert batch.box_heading_frustum[n] == one.box["heading_frustum"]


def reference_pairs(cameras, instances, rig_pairs):
    """Brute force over every two detections."""
    rows = []
    for number, (a, b) in enumerate(rig_pairs):
        for i in range(len(cameras)):
            for j in range(len(cameras)):
                if instances[i] and instances[i] == instances[j] and cameras[i] == a and cameras[j] == b:
                    rows.append((number, i, j))
    return sorted(rows)


def test_pairs_only_between_contiguous_cameras_of_one_instance():
    rig_pairs = ((0, 1), (1, 2), (2, 3), (3, 0))
    cameras = np.array([0, 1, 2, 0, 2, 1])
    instances = np.array(["a", "a", "a", "b", "b", ""])
    rows = contiguous_pairs(cameras, instances, rig_pairs)
    # a: cameras 0-1 (pair 0), 1-2 (pair 1); 0-2 are not contiguous. b: cameras 0 and 2 -> none.
    assert rows.tolist() == [[0, 0, 1], [1, 1, 2]] and rows.dtype == np.int64
    assert contiguous_pairs(np.array([0, 1]), np.array(["", ""]), rig_pairs).shape == (0, 3)
    assert contiguous_pairs(np.array([0, 1]), np.array(["a", "a"]), ()).shape == (0, 3)


@pytest.mark.parametrize("seed", range(10))
def test_pairs_equal_a_brute_force_reference(seed):
    rng = np.random.default_rng(seed)
    cameras = int(rng.integers(2, 7))
    count = int(rng.integers(0, 8 * cameras))
    rig_pairs = ((0, 1),) if cameras == 2 else tuple((k, (k + 1) % cameras) for k in range(cameras))
    # One detection per (instance, camera) at most, as association guarantees; some unassociated.
    slots = rng.permutation(8 * cameras)[:count]
    instances = np.where(rng.random(count) < 0.8, np.char.add("i", (slots // cameras).astype(str)), "")
    camera = slots % cameras
    rows = contiguous_pairs(camera, instances, rig_pairs)
    assert [tuple(row) for row in rows.tolist()] == reference_pairs(camera.tolist(), instances.tolist(), rig_pairs)


def test_schema_round_trip_and_atomic_shards(tmp_path):
    schemas = cache_schemas((1, 2, 2), "tiny")
    assert schemas["detections"] == with_metadata(detections_schema(8), "detections")  # names and types
    assert schemas["detections"].metadata[b"sianms.roi_feature_shape"] == b"1,2,2"
    assert schemas["frustums"].equals(with_metadata(FRUSTUMS_SCHEMA, "frustums"), check_metadata=True)
    assert schemas["pairs"].equals(with_metadata(PAIRS_SCHEMA, "pairs"), check_metadata=True)
    feature = np.arange(4, dtype="<f2").reshape(1, 2, 2)
    row = {name: None for name in schemas["detections"].names}
    row.update(detection_id="d", x1=1.5, score=0.5, overlap_pairs=["A|B"], roi_feature=feature.tobytes(),
               detection_index=0)
    table = pa.Table.from_pylist([row], schema=schemas["detections"])
    with ShardWriter(tmp_path, "s", schemas) as writer:
        writer.write("detections", table)
    assert not shard_done(tmp_path, "s") and not (tmp_path / "detections" / "s.parquet").exists()
    clear_shard(tmp_path, "s")
    assert not list(tmp_path.rglob("*.partial"))
    with ShardWriter(tmp_path, "s", schemas) as writer:
        writer.write("detections", table)
        record = writer.commit({"samples": 1})
    assert shard_done(tmp_path, "s") and record["files"]["detections/s.parquet"]["rows"] == 1
    back = pq.read_table(tmp_path / "detections" / "s.parquet")
    assert back.schema.names == schemas["detections"].names
    assert back.schema.metadata == schemas["detections"].metadata
    assert back.schema.field("roi_feature").type == pa.binary(8)
    assert back.to_pylist() == table.to_pylist()
    decoded = decode_roi_features(back.column("roi_feature"), (1, 2, 2), tmp_path / "detections")
    assert np.array_equal(decoded[0], feature)
    manifest = write_manifest(tmp_path, {"seed": 0}, ["s", "t"], tmp_path)
    assert manifest["counts"] == {"samples": 1, "detections": 1, "frustums": 0, "pairs": 0}
    assert manifest["missing_shards"] == ["t"] and not manifest["complete"]


@pytest.mark.parametrize("binary", [pa.binary(8), pa.binary(), pa.large_binary()])
def test_roi_features_decode_from_sliced_chunks_of_any_binary_type(binary):
    # A filtered read hands over chunks that are slices of larger buffers; each value is read from
    # where its slice starts.
    features = np.arange(5 * 4, dtype="<f2").reshape(5, 1, 2, 2)
    values = pa.array([feature.tobytes() for feature in features], binary)
    column = pa.chunked_array([values.slice(1, 2), values.slice(3, 2), values.slice(0, 1)])
    decoded = decode_roi_features(column, (1, 2, 2), Path("detections"))
    assert np.array_equal(decoded, features[[1, 2, 3, 4, 0]])
    assert np.array_equal(decode_roi_features(values.slice(2), (1, 2, 2), Path("d")), features[2:])
