"""Unit quaternions ordered (w, x, y, z), the nuScenes / pyquaternion convention.

All functions broadcast over leading dimensions: a quaternion array has shape (..., 4)
and a rotation-matrix array shape (..., 3, 3). Rotations are active: ``R @ p`` rotates
the point ``p``; the quaternion ``q`` and the matrix ``quat_to_matrix(q)`` rotate alike.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from sianms_cli.errors import SianmsError


def _normalise(q: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(~(norm > 0.0)):
        raise SianmsError("quaternion with zero or non-finite norm cannot be a rotation")
    return q / norm


def quat_to_matrix(q: ArrayLike) -> np.ndarray:
    """Rotation matrices of quaternions.

    Args:
        q: (..., 4) quaternions (w, x, y, z); normalised here, so any non-zero scale works.

    Returns:
        (..., 3, 3) float64 rotation matrices.

    Raises:
        SianmsError: a quaternion has zero or non-finite norm.
    """
    q = _normalise(np.asarray(q, dtype=np.float64))
    w, x, y, z = np.moveaxis(q, -1, 0)
    rows = (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def matrix_to_quat(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternions of rotation matrices, with w >= 0.

    Uses Shepperd's method: per matrix, the largest of the four diagonal-derived terms
    is taken as the pivot, which keeps the square root well conditioned.

    Args:
        rotation: (..., 3, 3) proper rotation matrices.

    Returns:
        (..., 4) float64 unit quaternions (w, x, y, z) with w >= 0 (q and -q are the
        same rotation; the sign is fixed so the output is unique except at w == 0).
    """
    m = np.asarray(rotation, dtype=np.float64)
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    trace = m00 + m11 + m22
    # Four times the square of each component, one per pivot choice.
    pivots = np.stack(
        [1 + trace, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], axis=-1
    )
    choice = np.argmax(pivots, axis=-1)
    s = 2.0 * np.sqrt(np.maximum(np.take_along_axis(pivots, choice[..., None], -1)[..., 0], 0.0))
    d21 = m[..., 2, 1] - m[..., 1, 2]
    d02 = m[..., 0, 2] - m[..., 2, 0]
    d10 = m[..., 1, 0] - m[..., 0, 1]
    s01 = m[..., 0, 1] + m[..., 1, 0]
    s02 = m[..., 0, 2] + m[..., 2, 0]
    s12 = m[..., 1, 2] + m[..., 2, 1]
    candidates = np.stack(
        [
            np.stack([s / 4, d21 / s, d02 / s, d10 / s], axis=-1),
            np.stack([d21 / s, s / 4, s01 / s, s02 / s], axis=-1),
            np.stack([d02 / s, s01 / s, s / 4, s12 / s], axis=-1),
            np.stack([d10 / s, s02 / s, s12 / s, s / 4], axis=-1),
        ],
        axis=-2,
    )
    q = np.take_along_axis(candidates, choice[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` (apply ``b`` first, then ``a``).

    Args:
        a, b: (..., 4) quaternions (w, x, y, z); broadcast against each other.

    Returns:
        (..., 4) float64 product, not renormalised.
    """
    aw, ax, ay, az = np.moveaxis(np.asarray(a, dtype=np.float64), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, dtype=np.float64), -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def yaw_to_quat(yaw: np.ndarray) -> np.ndarray:
    """Quaternions of rotations by ``yaw`` radians about +z.

    Args:
        yaw: (...) angles in radians, counter-clockwise seen from above.

    Returns:
        (..., 4) float64 quaternions ``[cos(yaw/2), 0, 0, sin(yaw/2)]``.
    """
    half = 0.5 * np.asarray(yaw, dtype=np.float64)
    zeros = np.zeros_like(half)
    return np.stack([np.cos(half), zeros, zeros, np.sin(half)], axis=-1)


def quat_yaw(q: np.ndarray) -> np.ndarray:
    """Heading of the rotated x axis, as the devkit's ``quaternion_yaw``.

    The unit x axis is rotated by ``q`` and the yaw is ``atan2(y, x)`` of the result,
    so pitch and roll do not leak into the heading. Meaningful in global, ego and lidar
    frames (z up), not in a camera frame.

    Args:
        q: (..., 4) quaternions (w, x, y, z); normalised here.

    Returns:
        (...) float64 yaw in radians, in [-pi, pi].
    """
    rotation = quat_to_matrix(q)
    return np.arctan2(rotation[..., 1, 0], rotation[..., 0, 0])
