import numpy as np
import pytest

from sianms_cli.errors import SianmsError
from sianms_cli.geometry.projection import view_points
from sianms_cli.geometry.camera_ring import CameraRig
from sianms_cli.geometry.transforms import apply_transform, invert_transform

RING = (
    "CAM_FRONT",
    "CAM_FRONT_RIGHT",
    "CAM_BACK_RIGHT",
    "CAM_BACK",
    "CAM_BACK_LEFT",
    "CAM_FRONT_LEFT",
)
# Reference section 4, Set A: yaw of each optical axis (ring order), and the angular width
# seen by both cameras of each contiguous pair for points at 1 m height on a circle.
SET_A_YAWS_DEG = (0.33, -56.40, -110.79, 179.86, 108.60, 55.16)
SET_A_OVERLAP_DEG = {
    10.0: (3.6, 6.7, 2.9, 0.0, 8.8, 5.0),
    20.0: (5.7, 8.6, 5.7, 1.7, 10.5, 7.1),
    50.0: (6.9, 9.7, 7.4, 3.4, 11.6, 8.4),
}


def ring_points(radius: float, azimuth_deg: np.ndarray, height: float = 1.0) -> np.ndarray:
    azimuth = np.radians(azimuth_deg)
    return np.stack(
        [radius * np.cos(azimuth), radius * np.sin(azimuth), np.full_like(azimuth, height)], axis=1
    )


def yaw_camera(yaw_deg: float) -> np.ndarray:
    """cam_to_ego of a level camera at the ego origin looking along azimuth ``yaw_deg``."""
    yaw = np.radians(yaw_deg)
    forward = [np.cos(yaw), np.sin(yaw), 0.0]
    right = [np.sin(yaw), -np.cos(yaw), 0.0]
    down = [0.0, 0.0, -1.0]
    transform = np.eye(4)
    transform[:3, :3] = np.column_stack([right, down, forward])
    return transform


def synthetic_rig(yaws_deg, channels, hfov_deg=100.0, size=(200, 100)) -> CameraRig:
    f = size[0] / 2 / np.tan(np.radians(hfov_deg) / 2)
    intrinsic = np.array([[f, 0.0, size[0] / 2], [0.0, f, size[1] / 2], [0.0, 0.0, 1.0]])
    return CameraRig.from_cameras(
        channels,
        np.repeat(intrinsic[None], len(yaws_deg), axis=0),
        np.array([yaw_camera(y) for y in yaws_deg]).reshape(-1, 4, 4),
        np.array([size] * len(yaws_deg)).reshape(-1, 2),
    )


def test_nuscenes_rig_is_sorted_clockwise(nuscenes_rig):
    assert nuscenes_rig.channels == RING
    np.testing.assert_allclose(np.degrees(nuscenes_rig.azimuths), SET_A_YAWS_DEG, atol=0.006)
    assert nuscenes_rig.contiguous_pairs == ((0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 0))
    assert nuscenes_rig.pair_names[0] == "CAM_FRONT|CAM_FRONT_RIGHT"
    assert nuscenes_rig.pair_names[5] == "CAM_FRONT_LEFT|CAM_FRONT"
    np.testing.assert_array_equal(nuscenes_rig.image_sizes, [[1600, 900]] * 6)


def test_rig_arrays_are_read_only(nuscenes_rig):
    with pytest.raises(ValueError):
        nuscenes_rig.intrinsics[0, 0, 0] = 1.0
    np.testing.assert_allclose(
        nuscenes_rig.ego_to_cam @ nuscenes_rig.cam_to_ego,
        np.broadcast_to(np.eye(4), (6, 4, 4)),
        atol=1e-12,
    )


@pytest.mark.parametrize("radius", sorted(SET_A_OVERLAP_DEG))
def test_nuscenes_overlap_widths(nuscenes_rig, radius):
    step = 0.01
    azimuths = np.arange(0.0, 360.0, step)
    seen_by_pair = nuscenes_rig.overlap_pairs(ring_points(radius, azimuths))
    widths = seen_by_pair.sum(axis=0) * step
    # The reference numbers have one decimal and come from 5-decimal rotations.
    np.testing.assert_allclose(widths, SET_A_OVERLAP_DEG[radius], atol=0.15)


def test_nuscenes_points_at_known_angles(nuscenes_rig):
    # At infinity FRONT reaches -31.42 deg (0.33 - atan(783.7 / 1266.4)) and FRONT_RIGHT
    # -23.75 deg (-56.40 + atan(808.0 / 1260.8)); BACK reaches 136.25 deg and BACK_LEFT
    # 140.82 deg. Their overlaps are centred near -27.6 and 138.5 deg.
    points = np.vstack(
        [
            ring_points(50.0, np.array([-27.6, 138.5, 0.0, 180.0, -20.0, -35.0])),
            ring_points(10.0, np.array([138.5])),
        ]
    )
    inside = nuscenes_rig.inside_cameras(points)
    overlap = nuscenes_rig.overlap_pairs(points)
    expected_overlap = np.zeros((7, 6), dtype=bool)
    expected_overlap[0, 0] = True  # FRONT|FRONT_RIGHT
    expected_overlap[1, 3] = True  # BACK|BACK_LEFT
    np.testing.assert_array_equal(overlap, expected_overlap)
    np.testing.assert_array_equal(nuscenes_rig.in_overlap(points), expected_overlap.any(axis=1))
    np.testing.assert_array_equal(inside[2], [True, False, False, False, False, False])
    np.testing.assert_array_equal(inside[3], [False, False, False, True, False, False])
    np.testing.assert_array_equal(inside[4], [True, False, False, False, False, False])
    np.testing.assert_array_equal(inside[5], [False, True, False, False, False, False])


def test_inside_cameras_matches_per_camera_projection(nuscenes_rig):
    rng = np.random.default_rng(13)
    points = np.column_stack([rng.uniform(-40, 40, size=(2000, 2)), rng.uniform(-2, 4, size=2000)])
    inside = nuscenes_rig.inside_cameras(points)
    assert inside.shape == (2000, 6)
    for c in range(6):
        points_cam = apply_transform(invert_transform(nuscenes_rig.cam_to_ego[c]), points)
        uv = view_points(points_cam, nuscenes_rig.intrinsics[c])
        expected = (
            (points_cam[:, 2] > 0)
            & (uv[:, 0] >= 0)
            & (uv[:, 0] < 1600)
            & (uv[:, 1] >= 0)
            & (uv[:, 1] < 900)
        )
        np.testing.assert_array_equal(inside[:, c], expected)


def test_image_bounds_are_half_open():
    intrinsic = np.array([[[100.0, 0.0, 100.0], [0.0, 100.0, 50.0], [0.0, 0.0, 1.0]]])
    rig = CameraRig.from_cameras(["CAM"], intrinsic, yaw_camera(0.0)[None], [[200, 100]])
    # Ego (10, 10, 0) projects to u = 0 (inside), (10, -10, 0) to u = W (outside).
    # Ego (10, 0, 5) projects to v = 0 (inside), (10, 0, -5) to v = H (outside).
    # Points at depth 0 or behind are never inside.
    points = np.array(
        [
            [10.0, 10.0, 0.0],
            [10.0, -10.0, 0.0],
            [10.0, 0.0, 5.0],
            [10.0, 0.0, -5.0],
            [0.0, 0.0, 0.0],
            [-10.0, 0.0, 0.0],
        ]
    )
    np.testing.assert_array_equal(
        rig.inside_cameras(points)[:, 0], [True, False, True, False, False, False]
    )


def test_four_camera_rig():
    rig = synthetic_rig([90.0, 180.0, 0.0, -90.0], ["LEFT", "BACK", "FRONT", "RIGHT"])
    assert rig.channels == ("FRONT", "RIGHT", "BACK", "LEFT")
    assert rig.pair_names == ("FRONT|RIGHT", "RIGHT|BACK", "BACK|LEFT", "LEFT|FRONT")
    # HFOV 100 deg every 90 deg: 10-deg overlaps centred on -45, -135, 135 and 45 deg.
    points = ring_points(
        20.0, np.array([-45.0, -44.0, -39.0, -51.0, -135.0, 135.0, 45.0, 0.0]), 0.0
    )
    expected = np.zeros((8, 4), dtype=bool)
    expected[0, 0] = expected[1, 0] = True
    expected[4, 1] = expected[5, 2] = expected[6, 3] = True
    np.testing.assert_array_equal(rig.overlap_pairs(points), expected)


def test_two_camera_rigs():
    back_to_back = synthetic_rig([180.0, 0.0], ["BACK", "FRONT"])
    assert back_to_back.channels == ("FRONT", "BACK")
    assert back_to_back.contiguous_pairs == ((0, 1),)
    assert back_to_back.pair_names == ("FRONT|BACK",)
    assert not back_to_back.in_overlap(ring_points(20.0, np.arange(0.0, 360.0, 0.5))).any()

    splayed = synthetic_rig([-60.0, 0.0], ["RIGHT", "FRONT"])
    assert splayed.channels == ("FRONT", "RIGHT")
    np.testing.assert_array_equal(
        splayed.in_overlap(ring_points(20.0, np.array([-30.0, -5.0, -55.0]))), [True, False, False]
    )


def test_single_camera_rig_has_no_overlap():
    rig = synthetic_rig([10.0], ["CAM"])
    assert rig.contiguous_pairs == () and rig.pair_names == ()
    assert rig.overlap_pairs(np.zeros((3, 3))).shape == (3, 0)
    np.testing.assert_array_equal(
        rig.in_overlap(ring_points(5.0, np.array([10.0, 50.0]))), [False, False]
    )


def test_tie_break_starts_on_the_left():
    rig = synthetic_rig([-30.0, 180.0, 30.0], ["R", "B", "L"])
    assert rig.channels == ("L", "R", "B")


def test_invalid_rigs_are_refused():
    with pytest.raises(SianmsError, match="unique"):
        synthetic_rig([0.0, 90.0], ["CAM", "CAM"])
    with pytest.raises(SianmsError, match="intrinsics"):
        CameraRig.from_cameras(["A"], np.eye(3)[None].repeat(2, 0), np.eye(4)[None], [[10, 10]])
    with pytest.raises(SianmsError, match="whole pixels"):
        CameraRig.from_cameras(["A"], np.eye(3)[None], np.eye(4)[None], [[10.5, 10]])
