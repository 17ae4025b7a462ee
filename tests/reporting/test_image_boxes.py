import numpy as np
import pytest

from sianms_cli.geometry.boxes import box_corners
from sianms_cli.geometry.clip import hull_in_rectangle
from sianms_cli.geometry.quaternion import quat_to_matrix, yaw_to_quat
from sianms_cli.geometry.projection import view_points
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.reporting.image_boxes import annotation_image_boxes, boxes_imaged

INTRINSIC = np.array([[100.0, 0.0, 80.0], [0.0, 100.0, 45.0], [0.0, 0.0, 1.0]])


def _imaged(centers, sizes, cameras=1, yaw=0.0):
    """``boxes_imaged`` with the global frame as the camera frame (x right, y down, z depth)."""
    centers = np.asarray(centers, dtype=float)
    n = len(centers)
    corners = box_corners(centers, np.asarray(sizes, dtype=float), yaw_to_quat(np.full(n, yaw)))
    rotation = np.broadcast_to(np.eye(3), (n, cameras, 3, 3)).copy()
    return boxes_imaged(corners, rotation, np.zeros((n, cameras, 3)),
                        np.broadcast_to(INTRINSIC, (n, cameras, 3, 3)), np.full((n, cameras, 2), [160.0, 90.0]))


def test_a_box_in_front_inside_the_image_is_imaged_and_one_behind_is_not():
    assert _imaged([[0, 0, 10], [0, 0, -10]], [[2, 2, 2]] * 2)[:, 0].tolist() == [True, False]


def test_a_box_whose_projection_misses_the_canvas_is_not_imaged():
    assert _imaged([[100, 0, 10], [0, -60, 10]], [[2, 2, 2]] * 2)[:, 0].tolist() == [False, False]


def test_a_box_straddling_an_image_edge_is_imaged():
    # Centre projects at u = 80 + 100 * 9 / 10 = 170 > 160; its left corners at u = 160 - ... inside.
    assert _imaged([[9, 0, 10]], [[4, 4, 2]])[0, 0]


def test_a_box_around_the_camera_plane_uses_only_its_corners_in_front():
    # Half the corners at z = +1 spread over the whole image: imaged.
    assert _imaged([[0, 0, 0]], [[2, 2, 2]])[0, 0]
    # A long box reaching from behind to just in front, off to the side: its true image is
    # a sliver at the right edge, but the devkit keeps only the corners at z > 0, whose hull
    # lies right of the image. Not imaged, as in the export script.
    centers, sizes = [[1.5, 0, -4.5]], [[1, 10, 1]]  # length 10 along z after yaw -90 deg
    assert not _imaged(centers, sizes, yaw=np.pi / 2)[0, 0]


def test_a_missing_camera_images_nothing():
    corners = box_corners(np.array([[0.0, 0, 10]]), np.array([[2.0, 2, 2]]), yaw_to_quat(np.zeros(1)))
    rotation = np.stack([np.eye(3), np.full((3, 3), np.nan)])[None]
    intrinsic = np.stack([INTRINSIC, np.full((3, 3), np.nan)])[None]
    imaged = boxes_imaged(corners, rotation, np.zeros((1, 2, 3)), intrinsic, np.array([[[160, 90], [0, 0]]]))
    assert imaged.tolist() == [[True, False]]


def _reference_imaged(db, annotation_row, channel):
    """The devkit's get_2d_boxes for one annotation and camera, record by record."""
    annotations = db.table("sample_annotation")
    sample_token = db.table("sample").tokens[annotations.rows("sample_token")[annotation_row]]
    token = db.keyframe_data(sample_token).get(channel)
    if token is None:
        return False
    ego_rotation, ego_translation = db.ego_pose_of(token)
    sensor_rotation, sensor_translation, intrinsic = db.calibration_of(token)
    corners = box_corners(annotations.column("translation")[annotation_row][None],
                          annotations.column("size")[annotation_row][None],
                          annotations.column("rotation")[annotation_row][None])[0]
    corners = (corners - ego_translation) @ quat_to_matrix(ego_rotation)
    corners = (corners - sensor_translation) @ quat_to_matrix(sensor_rotation)
    in_front = corners[:, 2] > 0
    uv = view_points(corners[in_front], intrinsic)[:, :2]
    row = db.table("sample_data").index(token)
    size = db.table("sample_data").column("width")[row], db.table("sample_data").column("height")[row]
    _, area = hull_in_rectangle(uv[None], np.ones((1, len(uv)), dtype=bool), *size)
    return bool(area[0] > 0)


def test_matches_a_record_by_record_port_on_a_synthetic_dataroot(tiny_dataroot):
    db = NuScenesDB(tiny_dataroot, "v1.0-mini")
    result = annotation_image_boxes(db, chunk=7)
    assert result.imaged.shape == (len(db.table("sample_annotation")), len(result.channels))
    assert len(result.channels) == 6
    rows = np.arange(0, len(result.imaged), max(len(result.imaged) // 60, 1))
    for row in rows:
        for c, channel in enumerate(result.channels):
            assert result.imaged[row, c] == _reference_imaged(db, row, channel), (row, channel)
    assert result.imaged[rows].any()


@pytest.mark.parametrize("chunk", [1, 5, 100_000])
def test_the_chunk_size_does_not_change_the_result(tiny_dataroot, chunk):
    db = NuScenesDB(tiny_dataroot, "v1.0-mini")
    assert np.array_equal(annotation_image_boxes(db, chunk=chunk).imaged, annotation_image_boxes(db).imaged)
