"""`num_lidar_pts` as nuscenes-devkit counts it: points_in_box on the key-frame sweep.

The devkit reads the sweep as float32 points in the LIDAR_TOP frame
(``LidarPointCloud.from_file``) and moves each annotated box there through its records
(``NuScenes.get_sample_data``): ``translate(-ego translation)``, ``rotate(Quaternion(ego
rotation).inverse)``, ``translate(-sensor translation)``, ``rotate(Quaternion(sensor
rotation).inverse)``, in float64 with pyquaternion's arithmetic; ``points_in_box`` then
projects the points, widened to float64, on three box edges from one corner.

Ground returns lie within millimetres of a box's bottom face, so a count made any other
way (global frame, float64 points) differs for a few boxes in ten thousand. This module
repeats the devkit's operations in the same order and precision, vectorised over each box
and the points near it; only the three-term projections are summed left to right where the
devkit's ``np.dot`` leaves the order to BLAS, which can tell apart only a point within a
rounding error (1e-16 relative) of a face.
The pyquaternion steps are written out as its source has them (v0.9.9, MIT licence):
``rotation_matrix`` normalises in place when the squared norm is more than 1e-14 from 1,
then reads the lower-right 3x3 block of ``Q(q) @ Qbar(q)^T``; ``inverse`` is the conjugate
over the squared norm; ``a * b`` is ``Q(a) @ b``.
"""

from __future__ import annotations

import numpy as np

_UNIT_TOLERANCE = 1e-14  # pyquaternion is_unit
_CELL = 2.0  # metres: the grid columns that find the points near a box
_BOUNDS_MARGIN = 1e-3
"""Metres around a box's corners within which its candidate points are taken: a point the
devkit counts lies inside the box up to rounding (1e-12 m here), far inside this margin."""


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

    Only the points near a box (:func:`_candidate_pairs`) are tested, with the devkit's
    arithmetic: the point widened to float64 minus the corner, projected on each edge, and
    compared with the edge's squared length. The projections are written out as products
    and sums, whose rounding is the same on every CPU, where a BLAS product's is not.
    """
    points = np.asarray(points_sensor, np.float32)
    corners = np.asarray(corners, np.float64)
    box, point = _candidate_pairs(points, corners)
    p1 = corners[:, :, 0]
    axes = np.stack([corners[:, :, 4] - p1, corners[:, :, 1] - p1, corners[:, :, 3] - p1], axis=1)  # (N, 3 axes, 3)
    limits = np.einsum("nak,nak->na", axes, axes)
    v = points[point].astype(np.float64) - p1[box]  # (M, 3)
    a = axes[box]
    projection = a[:, :, 0] * v[:, None, 0] + a[:, :, 1] * v[:, None, 1] + a[:, :, 2] * v[:, None, 2]
    inside = ((projection >= 0) & (projection <= limits[box])).all(axis=1)
    return np.bincount(box[inside], minlength=len(corners)).astype(np.int64)


def _candidate_pairs(points: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(box, point) index pairs of the points inside each box's axis-aligned bounds grown by
    :data:`_BOUNDS_MARGIN`: a superset of the points the devkit's test can count.

    The points are sorted into a grid of :data:`_CELL` metre columns in x and y; a box's
    bounds cover a few grid columns, in each of which its points are one contiguous run of
    the sorted order, so the cost follows the points near boxes, not boxes x points.
    """
    empty = np.zeros(0, np.int64)
    if len(points) == 0 or len(corners) == 0:
        return empty, empty
    xyz = points.astype(np.float64)
    cell = np.floor(xyz[:, :2] / _CELL).astype(np.int64)
    first = cell.min(axis=0)
    cell -= first
    rows = int(cell[:, 1].max()) + 1
    key = cell[:, 0] * rows + cell[:, 1]
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    low = corners.min(axis=2) - _BOUNDS_MARGIN
    high = corners.max(axis=2) + _BOUNDS_MARGIN
    low_cell = np.floor(low[:, :2] / _CELL).astype(np.int64) - first
    high_cell = np.floor(high[:, :2] / _CELL).astype(np.int64) - first
    low_cell, high_cell = np.maximum(low_cell, 0), np.minimum(high_cell, [int(cell[:, 0].max()), rows - 1])
    columns = np.maximum(high_cell[:, 0] - low_cell[:, 0] + 1, 0) * (high_cell[:, 1] >= low_cell[:, 1])
    column_box = np.repeat(np.arange(len(corners)), columns)
    column = low_cell[column_box, 0] + np.arange(len(column_box)) - np.repeat(np.cumsum(columns) - columns, columns)
    start = np.searchsorted(sorted_key, column * rows + low_cell[column_box, 1], side="left")
    stop = np.searchsorted(sorted_key, column * rows + high_cell[column_box, 1], side="right")
    length = stop - start
    box = np.repeat(column_box, length)
    point = order[np.arange(len(box)) - np.repeat(np.cumsum(length) - length - start, length)]
    near = np.all((xyz[point] >= low[box]) & (xyz[point] <= high[box]), axis=1)
    return box[near], point[near]
