"""synth.devkit_count: num_lidar_pts as the devkit counts it, from the records, on float32 points."""

import numpy as np
import pytest
from devkit_box import devkit_corners, devkit_points_in_box

from sianms_cli.geometry.quaternion import yaw_to_quat
from sianms_cli.synth.devkit_count import boxes_in_sensor_frame, count_points_in_boxes

EGO_TRANSLATION, EGO_ROTATION = np.array([612.3, 1804.7, 0.0]), yaw_to_quat(np.array(0.7))
SENSOR_TRANSLATION = np.array([0.94, 0.0, 1.84])
TILTED = np.array([0.7071, -0.0012, 0.0009, -0.7071])  # a LIDAR_TOP calibration: a quarter turn, 0.1 degree tilts
LEVEL = yaw_to_quat(np.array(-np.pi / 2))  # its faces square to the sensor's axes: their bounds' faces


def scene(seed: int, n_boxes: int = 80, sensor_rotation=TILTED):
    """Boxes around a sensor and float32 points: a scatter, points inside the boxes, and points
    on and within a few float32 steps of their bottom faces (where the arithmetic decides, and
    where a square box's face is its bounds' face)."""
    rng = np.random.default_rng(seed)
    center_ego = np.column_stack([rng.uniform(-55, 55, (n_boxes, 2)), rng.uniform(0.2, 1.5, n_boxes)])
    size = rng.uniform([0.3, 0.3, 0.6], [3.0, 12.0, 4.0], (n_boxes, 3))
    yaw = np.where(np.arange(n_boxes) % 2 == 0, rng.uniform(-np.pi, np.pi, n_boxes),
                   rng.integers(0, 4, n_boxes) * np.pi / 2)  # half of them square to the sensor's axes
    cos, sin = np.cos(0.7), np.sin(0.7)
    center = np.column_stack([cos * center_ego[:, 0] - sin * center_ego[:, 1],
                              sin * center_ego[:, 0] + cos * center_ego[:, 1], center_ego[:, 2]]) + EGO_TRANSLATION
    rotation = yaw_to_quat(yaw + 0.7)
    corners = boxes_in_sensor_frame(center, size, rotation, EGO_TRANSLATION, EGO_ROTATION, SENSOR_TRANSLATION,
                                    sensor_rotation)
    box = rng.integers(0, n_boxes, 30_000)
    weights = rng.uniform(0, 1, (len(box), 8))
    weights /= weights.sum(axis=1, keepdims=True)
    inside = np.einsum("pc,pkc->pk", weights, corners[box])
    face_corners = corners[box][:, :, [2, 3, 6, 7]]  # the bottom face, where ground returns lie
    w = rng.uniform(0, 1, (len(box), 4))
    face = np.einsum("pc,pkc->pk", w / w.sum(axis=1, keepdims=True), face_corners)
    steps = rng.integers(-3, 4, (len(box), 1)) * np.spacing(np.abs(face).astype(np.float32))
    scatter = np.column_stack([rng.uniform(-70, 70, (20_000, 2)), rng.uniform(-3, 3, 20_000)])
    points = np.concatenate([scatter, inside, face + steps]).astype(np.float32)
    return points, corners, center, size, rotation


@pytest.mark.parametrize("seed, sensor_rotation", [(0, TILTED), (1, TILTED), (2, LEVEL), (3, LEVEL)])
def test_counts_equal_the_devkits_points_in_box_on_every_box(seed, sensor_rotation):
    points, corners, *_ = scene(seed, sensor_rotation=sensor_rotation)
    expected = [int(devkit_points_in_box(corners[n], points.T.astype(np.float32)).sum()) for n in range(len(corners))]
    assert count_points_in_boxes(points, corners).tolist() == expected
    assert sum(expected) > 40_000  # the face points do decide: many are in, many out


def test_corners_follow_the_devkits_get_sample_data():
    _, corners, center, size, rotation = scene(3, n_boxes=5)
    for n in range(5):  # the devkit's Box moved to the sensor frame, in float64 with exact rotations
        box = devkit_corners(center[n], size[n], rotation[n])
        ego = np.linalg.inv(_transform(EGO_TRANSLATION, EGO_ROTATION))
        sensor = np.linalg.inv(_transform(SENSOR_TRANSLATION, TILTED / np.linalg.norm(TILTED)))
        expected = (sensor @ ego @ np.vstack([box, np.ones(8)]))[:3]
        np.testing.assert_allclose(corners[n], expected, atol=1e-9)


def test_no_boxes_or_no_points():
    points, corners, *_ = scene(4, n_boxes=3)
    assert count_points_in_boxes(points, corners[:0]).tolist() == []
    assert count_points_in_boxes(points[:0], corners).tolist() == [0, 0, 0]


def _transform(translation, rotation):
    from sianms_cli.geometry.quaternion import quat_to_matrix

    matrix = np.eye(4)
    matrix[:3, :3] = quat_to_matrix(np.asarray(rotation))
    matrix[:3, 3] = translation
    return matrix
