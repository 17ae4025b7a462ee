import numpy as np
import pytest

from sianms_cli.geometry.boxes import box_corners
from sianms_cli.geometry.quaternion import quat_to_matrix, quat_yaw, yaw_to_quat
from sianms_cli.geometry.transforms import (
    apply_transform,
    global_to_sensor,
    invert_transform,
    make_transform,
    sensor_to_global,
    transform_boxes,
)


def test_make_transform_maps_child_to_parent():
    transform = make_transform(yaw_to_quat(np.pi / 2), [1.0, 2.0, 3.0])
    mapped = apply_transform(transform, np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]))
    np.testing.assert_allclose(mapped, [[1.0, 3.0, 3.0], [1.0, 2.0, 3.0]], atol=1e-15)
    np.testing.assert_array_equal(transform[3], [0, 0, 0, 1])


def test_invert_transform():
    transform = make_transform([0.3, -0.2, 0.9, 0.1], [4.0, -5.0, 6.0])
    np.testing.assert_allclose(invert_transform(transform) @ transform, np.eye(4), atol=1e-14)
    np.testing.assert_allclose(invert_transform(transform), np.linalg.inv(transform), atol=1e-14)


def test_apply_transform_empty():
    assert apply_transform(np.eye(4), np.zeros((0, 3))).shape == (0, 3)


def test_transform_boxes_centre_and_yaw():
    transform = make_transform(yaw_to_quat(np.pi / 2), [0.0, 0.0, 1.0])
    center, rotation = transform_boxes(transform, [[1.0, 0.0, 0.0]], yaw_to_quat([0.25]))
    np.testing.assert_allclose(center, [[0.0, 1.0, 1.0]], atol=1e-15)
    assert quat_yaw(rotation)[0] == pytest.approx(np.pi / 2 + 0.25, abs=1e-12)


def test_transform_boxes_moves_corners_rigidly():
    rng = np.random.default_rng(4)
    center = rng.normal(size=(5, 3))
    size = rng.uniform(0.5, 4.0, size=(5, 3))
    rotation = rng.normal(size=(5, 4))
    transform = make_transform(rng.normal(size=4), rng.normal(size=3))
    new_center, new_rotation = transform_boxes(transform, center, rotation)
    moved = apply_transform(transform, box_corners(center, size, rotation).reshape(-1, 3))
    np.testing.assert_allclose(
        box_corners(new_center, size, new_rotation), moved.reshape(5, 8, 3), atol=1e-12
    )


def test_global_sensor_round_trip_with_real_calibration(set_a_cameras, set_a_ego_pose):
    cam_translation, cam_rotation = set_a_cameras["CAM_FRONT"][:2]
    ego_rotation, ego_translation = set_a_ego_pose
    to_global = sensor_to_global(ego_rotation, ego_translation, cam_rotation, cam_translation)
    to_sensor = global_to_sensor(ego_rotation, ego_translation, cam_rotation, cam_translation)
    np.testing.assert_allclose(to_sensor @ to_global, np.eye(4), atol=1e-12)

    points_global = np.array([[420.0, 1175.0, 1.0], [411.0, 1181.0, 0.0], [390.5, 1200.25, 3.0]])
    points_cam = apply_transform(to_sensor, points_global)
    np.testing.assert_allclose(apply_transform(to_global, points_cam), points_global, atol=1e-10)

    # The devkit's chain, spelled out.
    r_ego, r_cam = quat_to_matrix(ego_rotation), quat_to_matrix(cam_rotation)
    expected = (points_global - ego_translation) @ r_ego
    expected = (expected - cam_translation) @ r_cam
    np.testing.assert_allclose(points_cam, expected, atol=1e-10)


def test_sensor_to_global_places_the_camera(set_a_cameras, set_a_ego_pose):
    cam_translation, cam_rotation = set_a_cameras["CAM_FRONT"][:2]
    ego_rotation, ego_translation = set_a_ego_pose
    to_global = sensor_to_global(ego_rotation, ego_translation, cam_rotation, cam_translation)
    origin = apply_transform(to_global, np.zeros((1, 3)))[0]
    expected = quat_to_matrix(ego_rotation) @ np.array(cam_translation) + ego_translation
    np.testing.assert_allclose(origin, expected, atol=1e-12)
    # The optical axis is horizontal to within 1.2 deg (reference section 4), and the ego
    # pose is nearly level, so the axis stays near the ground plane in global.
    axis = to_global[:3, 2]
    assert abs(np.degrees(np.arcsin(axis[2]))) < 2.5
