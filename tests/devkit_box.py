"""The devkit's points_in_box and Box.corners, transcribed (nuscenes-devkit data_classes / geometry_utils), for tests
that hold our counts against it without the devkit installed."""

import numpy as np

from sianms_cli.geometry.quaternion import quat_to_matrix


def devkit_points_in_box(corners, points):
    """points_in_box of the devkit, transcribed, on (3, 8) corners and (3, P) points."""
    p1, p_x, p_y, p_z = corners[:, 0], corners[:, 4], corners[:, 1], corners[:, 3]
    i, j, k = p_x - p1, p_y - p1, p_z - p1
    v = points - p1.reshape((-1, 1))
    iv, jv, kv = np.dot(i, v), np.dot(j, v), np.dot(k, v)
    mask_x = np.logical_and(0 <= iv, iv <= np.dot(i, i))
    mask_y = np.logical_and(0 <= jv, jv <= np.dot(j, j))
    mask_z = np.logical_and(0 <= kv, kv <= np.dot(k, k))
    return mask_x & mask_y & mask_z


def devkit_corners(center, size, rotation):
    """Box.corners() of the devkit, transcribed (3, 8), for one box."""
    w, length, h = size
    x = length / 2 * np.array([1, 1, 1, 1, -1, -1, -1, -1])
    y = w / 2 * np.array([1, -1, -1, 1, 1, -1, -1, 1])
    z = h / 2 * np.array([1, 1, -1, -1, 1, 1, -1, -1])
    return quat_to_matrix(rotation) @ np.vstack([x, y, z]) + np.reshape(center, (3, 1))
