"""`num_lidar_pts` as nuscenes-devkit counts it: points_in_box on the key-frame sweep.

The devkit reads the sweep as float32 points in the LIDAR_TOP frame
(``LidarPointCloud.from_file``) and moves each annotated box there through its records
(``NuScenes.get_sample_data``): ``translate(-ego translation)``, ``rotate(Quaternion(ego
rotation).inverse)``, ``translate(-sensor translation)``, ``rotate(Quaternion(sensor
rotation).inverse)``, in float64 with pyquaternion's arithmetic; ``points_in_box`` then
projects the points, widened to float64, on three box edges from one corner.

Ground returns lie within millimetres of a box's bottom face, so a count made any other
way (global frame, float64 points) differs for a few boxes in ten thousand. This module
repeats the devkit's operations in the same order and precision, vectorised over boxes.
The pyquaternion steps are written out as its source has them (v0.9.9, MIT licence):
``rotation_matrix`` normalises in place when the squared norm is more than 1e-14 from 1,
then reads the lower-right 3x3 block of ``Q(q) @ Qbar(q)^T``; ``inverse`` is the conjugate
over the squared norm; ``a * b`` is ``Q(a) @ b``.
"""

from __future__ import annotations

import numpy as np

_UNIT_TOLERANCE = 1e-14  # pyquaternion is_unit
_CHUNK_POINTS = 2_000_000  # boxes x points evaluated at once (tens of MB of float64)


def _q_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4, 4) left-multiplication matrix of quaternions (..., 4) (pyquaternion _q_matrix)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([np.stack([w, -x, -y, -z], -1), np.stack([x, w, -z, y], -1),
                     np.stack([y, z, w, -x], -1), np.stack([z, -y, x, w], -1)], -2)


def _q_bar_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4, 4) right-multiplication matrix (pyquaternion _q_bar_matrix)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([np.stack([w, -x, -y, -z], -1), np.stack([x, w, z, -y], -1),
                     np.stack([y, -z, w, x], -1), np.stack([z, y, -x, w], -1)], -2)


def _normalised(q: np.ndarray) -> np.ndarray:
    """pyquaternion _normalise: divide by the norm unless the squared norm is within 1e-14 of 1."""
    squares = np.einsum("...i,...i->...", q, q)
    unit = np.abs(1.0 - squares) < _UNIT_TOLERANCE
    return np.where(unit[..., None], q, q / np.sqrt(squares)[..., None])


def _rotation_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 3, 3) pyquaternion rotation_matrix of (already normalised) quaternions."""
    product = _q_matrix(q) @ np.swapaxes(_q_bar_matrix(q), -1, -2)
    return product[..., 1:, 1:]


def _inverse(q: np.ndarray) -> np.ndarray:
    """pyquaternion inverse: conjugate over the squared norm."""
    return np.concatenate([q[..., :1], -q[..., 1:]], axis=-1) / np.einsum("...i,...i->...", q, q)[..., None]


def boxes_in_sensor_frame(center, size, rotation, ego_translation, ego_rotation, sensor_translation,
                          sensor_rotation) -> np.ndarray:
    """(N, 3, 8) corners of boxes in the sensor frame, as devkit Box.corners() after get_sample_data.

    center (N,3), size (N,3) w,l,h, rotation (N,4) w,x,y,z: the annotation records' values;
    the ego pose and calibrated_sensor records' translation (3,) and rotation (4,).
    """
    center = np.asarray(center, np.float64)
    orientation = np.asarray(rotation, np.float64)
    for translation, quaternion in ((ego_translation, ego_rotation), (sensor_translation, sensor_rotation)):
        inverse = _normalised(_inverse(np.asarray(quaternion, np.float64)))  # normalised by rotation_matrix
        center = center + -np.asarray(translation, np.float64)
        center = center @ _rotation_matrix(inverse).T
        orientation = np.einsum("ij,nj->ni", _q_matrix(inverse), orientation)
    w, l, h = (np.asarray(size, np.float64) * 1.0).T
    signs = np.array([[1, 1, 1, 1, -1, -1, -1, -1], [1, -1, -1, 1, 1, -1, -1, 1], [1, 1, -1, -1, 1, 1, -1, -1]])
    local = np.stack([l[:, None] / 2 * signs[0], w[:, None] / 2 * signs[1], h[:, None] / 2 * signs[2]], axis=1)
    return _rotation_matrix(_normalised(orientation)) @ local + center[:, :, None]


def count_points_in_boxes(points_sensor: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(N,) int64 number of points inside each box, as devkit points_in_box counts them.

    points_sensor (P,3) float32 as the file holds them; corners (N,3,8) from
    :func:`boxes_in_sensor_frame`. A point inside two boxes counts for both.
    """
    points = np.asarray(points_sensor, np.float32).T  # (3, P), as LidarPointCloud.points[:3]
    p1 = corners[:, :, 0]
    axes = np.stack([corners[:, :, 4] - p1, corners[:, :, 1] - p1, corners[:, :, 3] - p1], axis=1)  # (N, 3 axes, 3)
    limits = np.einsum("nak,nak->na", axes, axes)
    counts = np.zeros(len(corners), np.int64)
    per_chunk = max(1, _CHUNK_POINTS // max(points.shape[1], 1))
    for start in range(0, len(corners), per_chunk):
        sl = slice(start, start + per_chunk)
        v = points[None, :, :] - p1[sl, :, None]  # float32 - float64 -> float64, (n, 3, P)
        projection = axes[sl] @ v  # (n, 3 axes, P)
        inside = ((projection >= 0) & (projection <= limits[sl, :, None])).all(axis=1)
        counts[sl] = inside.sum(axis=1)
    return counts
