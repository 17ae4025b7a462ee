import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from sianms_cli.data.cache import ShardWriter, clear_shard, decode_roi_features, shard_done, write_manifest
from sianms_cli.data.frustums import extract_frustum, heading_in_camera
from sianms_cli.data.pairs import contiguous_pairs
from sianms_cli.data.schemas import FRUSTUMS_SCHEMA, PAIRS_SCHEMA, detections_schema, with_metadata

K = np.array([[100.0, 0, 50], [0, 100, 50], [0, 0, 1]])


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


def test_pairs_only_between_contiguous_cameras_of_one_instance():
    rig_pairs = ((0, 1), (1, 2), (2, 3), (3, 0))
    cameras = np.array([0, 1, 2, 0, 2, 1])
    instances = np.array(["a", "a", "a", "b", "b", ""])
    rows = contiguous_pairs(cameras, instances, rig_pairs)
    # a: cameras 0-1 (pair 0), 1-2 (pair 1); 0-2 are not contiguous. b: cameras 0 and 2 -> none.
    assert rows == [(0, 0, 1), (1, 1, 2)]
    assert contiguous_pairs(np.array([0, 1]), np.array(["", ""]), rig_pairs) == []


def test_schema_round_trip_and_atomic_shards(tmp_path):
    schemas = {"detections": with_metadata(detections_schema(8), "detections", {"sianms.roi_feature_shape": "1,2,2"}),
               "frustums": with_metadata(FRUSTUMS_SCHEMA, "frustums"), "pairs": with_metadata(PAIRS_SCHEMA, "pairs")}
    feature = np.arange(4, dtype="<f2").reshape(1, 2, 2)
    row = {name: None for name in schemas["detections"].names}
    row.update(detection_id="d", x1=1.5, score=0.5, overlap_pairs=["A|B"], roi_feature=feature.tobytes(), detection_index=0)
    table = pa.Table.from_pylist([row], schema=schemas["detections"])
    with ShardWriter(tmp_path, "s", schemas) as writer:
        writer.write("detections", table)
    assert not shard_done(tmp_path, "s") and not (tmp_path / "detections" / "s.parquet").exists()
    clear_shard(tmp_path, "s")
    assert not list(tmp_path.rglob("*.tmp"))
    with ShardWriter(tmp_path, "s", schemas) as writer:
        writer.write("detections", table)
        record = writer.commit({"samples": 1})
    assert shard_done(tmp_path, "s") and record["files"]["detections/s.parquet"]["rows"] == 1
    back = pq.read_table(tmp_path / "detections" / "s.parquet")
    assert back.schema.names == schemas["detections"].names
    assert back.schema.metadata == schemas["detections"].metadata
    assert back.schema.field("roi_feature").type == pa.binary(8)
    assert back.to_pylist() == table.to_pylist()
    assert np.array_equal(decode_roi_features(back.column("roi_feature"), (1, 2, 2))[0], feature)
    manifest = write_manifest(tmp_path, {"seed": 0}, ["s", "t"])
    assert manifest["counts"] == {"samples": 1, "detections": 1, "frustums": 0, "pairs": 0}
    assert manifest["missing_shards"] == ["t"] and not manifest["complete"]
