import numpy as np
import pytest

from sianms_cli.errors import SianmsError
from sianms_cli.geometry.frustum import (
    frustum_angle,
    frustum_corners,
    frustum_members,
    points_in_frustum,
    rotate_from_frustum,
    rotate_to_frustum,
)

K = np.array([[100.0, 0.0, 100.0], [0.0, 100.0, 50.0], [0.0, 0.0, 1.0]])
BOX = np.array([90.0, 40.0, 110.0, 60.0])


def test_points_in_frustum_hand_cases():
    points = np.array(
        [
            [0.0, 0.0, 10.0],  # (100, 50): centre
            [1.0, 1.0, 10.0],  # (110, 60): corner, inclusive
            [1.0 + 2**-20, 0.0, 10.0],  # just right of the box
            [0.0, -1.0 - 2**-20, 10.0],  # just above the box
            [0.0, 0.0, -10.0],  # behind the camera, projects to the centre
            [0.0, 0.0, 0.0],  # at the camera centre
        ]
    )
    np.testing.assert_array_equal(
        points_in_frustum(points, BOX, K), [True, True, False, False, False, False]
    )


def test_points_in_frustum_depth_window_is_exclusive():
    points = np.array([[0.0, 0.0, 5.0], [0.0, 0.0, 5.5], [0.0, 0.0, 19.9], [0.0, 0.0, 20.0]])
    np.testing.assert_array_equal(
        points_in_frustum(points, BOX, K, min_depth=5.0, max_depth=20.0), [False, True, True, False]
    )


def test_frustum_angle_hand_values():
    boxes = np.array(
        [
            [90.0, 40.0, 110.0, 60.0],  # centred on the principal point
            [190.0, 40.0, 210.0, 60.0],  # centre u = 200: ray (1, 0, 1)
            [-10.0, 0.0, 10.0, 20.0],  # centre u = 0, v = 10: ray (-1, -0.4, 1)
        ]
    )
    np.testing.assert_allclose(frustum_angle(boxes, K), [0.0, np.pi / 4, -np.pi / 4], atol=1e-15)


def test_rotated_centre_ray_lies_on_plus_z():
    boxes = np.array(
        [[150.0, 40.0, 250.0, 60.0], [-80.0, 30.0, 0.0, 70.0], [20.0, 0.0, 60.0, 40.0]]
    )
    angles = frustum_angle(boxes, K)
    centers = 0.5 * (boxes[:, :2] + boxes[:, 2:])
    for n in range(len(boxes)):
        ray = np.array([(centers[n, 0] - 100) / 100, (centers[n, 1] - 50) / 100, 1.0]) * 7.0
        rotated = rotate_to_frustum(ray[None], angles[n])[0]
        # Rotation about y keeps y; x vanishes and z takes the ray's length in the x-z plane.
        np.testing.assert_allclose(rotated, [0.0, ray[1], np.hypot(ray[0], ray[2])], atol=1e-12)
    # A box centred at v = cy: the ray itself ends on +z.
    rotated = rotate_to_frustum(np.array([[7.0, 0.0, 7.0]]), frustum_angle(boxes[:1], K)[0])
    np.testing.assert_allclose(rotated, [[0.0, 0.0, 7.0 * np.sqrt(2)]], atol=1e-12)


def test_rotate_sign_convention():
    # rotate_pc_along_y of Frustum PointNets: x' = cos a x - sin a z, z' = sin a x + cos a z.
    rotated = rotate_to_frustum(np.array([[1.0, 2.0, 0.0]]), np.pi / 2)
    np.testing.assert_allclose(rotated, [[0.0, 2.0, 1.0]], atol=1e-15)


def test_rotate_round_trip():
    points = np.random.default_rng(12).normal(size=(100, 3))
    back = rotate_from_frustum(rotate_to_frustum(points, 0.7), 0.7)
    np.testing.assert_allclose(back, points, atol=1e-14)


def test_frustum_corners():
    corners = frustum_corners(BOX, K, near=1.0, far=10.0)
    near_face = [[-0.1, -0.1, 1.0], [0.1, -0.1, 1.0], [0.1, 0.1, 1.0], [-0.1, 0.1, 1.0]]
    np.testing.assert_allclose(
        corners, np.vstack([near_face, 10.0 * np.array(near_face)]), atol=1e-15
    )
    # Pulled slightly towards the axis, every corner is inside the frustum.
    shrunk = corners * [0.999, 0.999, 1.0]
    assert points_in_frustum(shrunk, BOX, K, min_depth=0.5, max_depth=11.0).all()


def test_frustum_corners_rejects_bad_depths():
    with pytest.raises(SianmsError):
        frustum_corners(BOX, K, near=5.0, far=5.0)
    with pytest.raises(SianmsError):
        frustum_corners(BOX, K, near=-1.0, far=5.0)


@pytest.mark.parametrize("mask_bytes", [1, 64, 1 << 24])
def test_frustum_members_of_all_boxes_equal_the_one_box_test(mask_bytes):
    rng = np.random.default_rng(7)
    points = np.stack([rng.uniform(-20, 20, 2000), rng.uniform(-5, 5, 2000), rng.uniform(-10, 60, 2000)], axis=1)
    points[:10] = [[1.0, 1.0, 10.0]] * 10  # on a corner of BOX: bounds are inclusive
    x1, y1 = rng.uniform(-50, 200, 40), rng.uniform(-20, 100, 40)
    boxes = np.concatenate([[BOX], np.stack([x1, y1, x1 + rng.uniform(0, 80, 40), y1 + rng.uniform(0, 50, 40)], 1)])
    box, point = frustum_members(points, boxes, K, 1.0, 50.0, max_mask_bytes=mask_bytes)
    expected = [np.flatnonzero(points_in_frustum(points, b, K, 1.0, 50.0)) for b in boxes]
    assert np.array_equal(box, np.repeat(np.arange(len(boxes)), [len(e) for e in expected]))
    assert np.array_equal(point, np.concatenate(expected))
    assert len(point) > 100 and set(range(10)) <= set(point[box == 0].tolist())
    none = frustum_members(points, np.zeros((0, 4)), K)
    assert none[0].shape == none[1].shape == (0,)
