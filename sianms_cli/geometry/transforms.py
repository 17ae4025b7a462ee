"""Rigid 4x4 homogeneous transforms between the global, ego and sensor frames.

A transform ``T`` named ``child_to_parent`` maps points expressed in the child frame
into the parent frame: ``p_parent = R @ p_child + t`` with ``R = T[:3, :3]`` and
``t = T[:3, 3]``. nuScenes records (ego_pose, calibrated_sensor) give exactly such
child-to-parent rotations and translations.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from sianms_cli.geometry.quaternion import matrix_to_quat, quat_multiply, quat_to_matrix


def make_transform(rotation_quat: ArrayLike, translation: ArrayLike) -> np.ndarray:
    """Child-to-parent transform of a pose record.

    Args:
        rotation_quat: (4,) quaternion (w, x, y, z) of the child frame in the parent frame.
        translation: (3,) origin of the child frame in the parent frame, metres.

    Returns:
        (4, 4) float64 matrix with ``p_parent = R p_child + t``.
    """
    transform = np.eye(4)
    transform[:3, :3] = quat_to_matrix(rotation_quat)
    transform[:3, 3] = np.asarray(translation, dtype=np.float64)
    return transform


def invert_transform(transform: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform, using ``R^T`` rather than a general inverse.

    Args:
        transform: (4, 4) rigid transform.

    Returns:
        (4, 4) float64 inverse: ``[[R^T, -R^T t], [0, 1]]``.
    """
    transform = np.asarray(transform, dtype=np.float64)
    rotation_t = transform[:3, :3].T
    inverse = np.eye(4)
    inverse[:3, :3] = rotation_t
    inverse[:3, 3] = -rotation_t @ transform[:3, 3]
    return inverse


def apply_transform(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map points through a rigid transform.

    Args:
        transform: (4, 4) transform from the points' frame to the target frame.
        points: (N, 3) points, metres.

    Returns:
        (N, 3) float64 points in the target frame; N may be 0.
    """
    transform = np.asarray(transform, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return points @ transform[:3, :3].T + transform[:3, 3]


def transform_boxes(
    transform: np.ndarray, center: np.ndarray, rotation: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Move boxes into another frame; a box's size (w, l, h) does not change.

    Args:
        transform: (4, 4) rigid transform from the boxes' frame to the target frame.
        center: (N, 3) box centres, metres.
        rotation: (N, 4) box orientations (w, x, y, z) in the source frame.

    Returns:
        ``(center, rotation)``: (N, 3) centres and (N, 4) orientations in the target
        frame, the orientation being ``q_T * q`` as the devkit's ``Box.rotate`` does.
    """
    transform = np.asarray(transform, dtype=np.float64)
    rotation = np.asarray(rotation, dtype=np.float64).reshape(-1, 4)
    frame_quat = matrix_to_quat(transform[:3, :3])
    return apply_transform(transform, center), quat_multiply(frame_quat, rotation)


def sensor_to_global(
    ego_rotation: np.ndarray,
    ego_translation: np.ndarray,
    sensor_rotation: np.ndarray,
    sensor_translation: np.ndarray,
) -> np.ndarray:
    """Sensor-to-global transform: sensor -> ego (calibrated_sensor) -> global (ego_pose).

    Args:
        ego_rotation, ego_translation: (4,), (3,) the ego_pose record.
        sensor_rotation, sensor_translation: (4,), (3,) the calibrated_sensor record.

    Returns:
        (4, 4) float64 ``p_global = T @ p_sensor``.
    """
    ego_to_global = make_transform(ego_rotation, ego_translation)
    sensor_to_ego = make_transform(sensor_rotation, sensor_translation)
    return ego_to_global @ sensor_to_ego


def global_to_sensor(
    ego_rotation: np.ndarray,
    ego_translation: np.ndarray,
    sensor_rotation: np.ndarray,
    sensor_translation: np.ndarray,
) -> np.ndarray:
    """Global-to-sensor transform, the inverse of :func:`sensor_to_global`.

    Equivalent to the devkit's chain: subtract the ego translation, rotate by R_ego^T,
    subtract the sensor translation, rotate by R_sensor^T.

    Returns:
        (4, 4) float64 ``p_sensor = T @ p_global``.
    """
    global_to_ego = invert_transform(make_transform(ego_rotation, ego_translation))
    ego_to_sensor = invert_transform(make_transform(sensor_rotation, sensor_translation))
    return ego_to_sensor @ global_to_ego
