"""Frustums of 2D boxes in a camera frame, as used by Frustum PointNets.

Camera frame: x right, y down, z forward, metres. A 2D box is [x1, y1, x2, y2] in
pixels. Frustum PointNets normalises each frustum by rotating its points about the
camera's y axis until the ray through the 2D box centre lies in the y-z plane, pointing
along +z; :func:`frustum_angle` gives that angle and :func:`rotate_to_frustum` applies it.
"""

from __future__ import annotations

import numpy as np

from sianms_cli.errors import SianmsError

# Upper bound on the bytes of the (boxes x points) mask in frustum_members.
_MASK_BYTES = 16 * 1024 * 1024


def points_in_frustum(
    points_cam: np.ndarray,
    box2d: np.ndarray,
    intrinsic: np.ndarray,
    min_depth: float = 0.0,
    max_depth: float = np.inf,
) -> np.ndarray:
    """Points whose projection falls inside a 2D box.

    Args:
        points_cam: (P, 3) points in the camera frame.
        box2d: (4,) [x1, y1, x2, y2] pixels; the bounds are inclusive.
        intrinsic: (3, 3) camera matrix.
        min_depth, max_depth: depth window, exclusive at both ends, metres; points at
            or behind the camera (z <= 0) are never inside, whatever ``min_depth``.

    Returns:
        (P,) bool: ``max(min_depth, 0) < z < max_depth`` and ``x1 <= u <= x2``,
        ``y1 <= v <= y2``.
    """
    in_depth, u, v = _pixels_in_depth(points_cam, intrinsic, min_depth, max_depth)
    x1, y1, x2, y2 = np.asarray(box2d, dtype=np.float64)
    return in_depth & (u >= x1) & (u <= x2) & (v >= y1) & (v <= y2)


def frustum_members(
    points_cam: np.ndarray,
    boxes2d: np.ndarray,
    intrinsic: np.ndarray,
    min_depth: float = 0.0,
    max_depth: float = np.inf,
    max_mask_bytes: int = _MASK_BYTES,
) -> tuple[np.ndarray, np.ndarray]:
    """Which points lie in the frustum of which 2D box, for all boxes of one camera at once.

    The same test as :func:`points_in_frustum`, row for row: the points are projected once
    (not once per box) and only those inside the depth window are tested against the boxes,
    a chunk of boxes at a time so the (boxes x points) mask stays under ``max_mask_bytes``.

    Args:
        points_cam: (P, 3) points in the camera frame.
        boxes2d: (N, 4) [x1, y1, x2, y2] pixels; bounds inclusive.
        intrinsic: (3, 3) camera matrix.
        min_depth, max_depth: depth window as :func:`points_in_frustum`.
        max_mask_bytes: bound on the temporary boolean mask.

    Returns:
        ``(box, point)``: (M,) int64 each, one entry per (box, point inside it), sorted by box
        then point: the frustum of box n is ``point[box == n]``, in point order.
    """
    boxes2d = np.asarray(boxes2d, dtype=np.float64).reshape(-1, 4)
    in_depth, u, v = _pixels_in_depth(points_cam, intrinsic, min_depth, max_depth)
    candidates = np.flatnonzero(in_depth)
    u, v = u[candidates], v[candidates]
    chunk = max(1, max_mask_bytes // max(1, len(candidates)))
    boxes, points = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)]
    for start in range(0, len(boxes2d), chunk):
        x1, y1, x2, y2 = (boxes2d[start:start + chunk, j, None] for j in range(4))
        inside = (u >= x1) & (u <= x2) & (v >= y1) & (v <= y2)
        box, point = np.nonzero(inside)
        boxes.append(box + start)
        points.append(candidates[point])
    return np.concatenate(boxes), np.concatenate(points)


def _pixels_in_depth(
    points_cam: np.ndarray, intrinsic: np.ndarray, min_depth: float, max_depth: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(P,) bool inside the depth window (and in front), and (P,) u, v pixel coordinates."""
    points_cam = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    depth = points_cam[:, 2]
    in_depth = (depth > min_depth) & (depth < max_depth) & (depth > 0)
    projected = points_cam @ np.asarray(intrinsic, dtype=np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        u = projected[:, 0] / projected[:, 2]
        v = projected[:, 1] / projected[:, 2]
    return in_depth, u, v


def pixel_rays(pixels: np.ndarray, intrinsic: np.ndarray) -> np.ndarray:
    """(N, 2) pixels -> (N, 3) camera-frame rays scaled to depth 1."""
    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    homogeneous = np.concatenate([pixels, np.ones((len(pixels), 1))], axis=1)
    rays = homogeneous @ np.linalg.inv(np.asarray(intrinsic, dtype=np.float64)).T
    return rays / rays[:, 2:3]


def frustum_angle(box2d: np.ndarray, intrinsic: np.ndarray) -> np.ndarray:
    """Rotation angle that centres each frustum on +z (Frustum PointNets' rot_angle).

    The 2D box centre is lifted to a ray (x, y, z) in the camera frame and the angle is
    ``pi/2 - atan2(z, x)``; it equals Frustum PointNets' ``pi/2 + frustum_angle``.
    A box centred on the principal point gives 0; a box right of it (x > 0) gives a
    positive angle. Values lie in (-pi/2, pi/2).

    Args:
        box2d: (N, 4) [x1, y1, x2, y2] pixels.
        intrinsic: (3, 3) camera matrix.

    Returns:
        (N,) float64 radians, for :func:`rotate_to_frustum`.
    """
    box2d = np.asarray(box2d, dtype=np.float64).reshape(-1, 4)
    centers = 0.5 * (box2d[:, :2] + box2d[:, 2:])
    rays = pixel_rays(centers, intrinsic)
    return np.pi / 2 - np.arctan2(rays[:, 2], rays[:, 0])


def rotate_to_frustum(points_cam: np.ndarray, angle: float | np.ndarray) -> np.ndarray:
    """Rotate camera-frame points into the frustum frame of ``angle``.

    Sign convention (that of Frustum PointNets' ``rotate_pc_along_y``):
    ``x' = cos(a) x - sin(a) z``, ``z' = sin(a) x + cos(a) z``, ``y' = y``. In the
    right-handed sense this is a rotation by ``-a`` about +y. With ``a`` from
    :func:`frustum_angle`, the box-centre ray (x, y, z) maps to (0, y, hypot(x, z)).

    Args:
        points_cam: (P, 3) camera-frame points.
        angle: radians, one for all points or (P,) one per point (the frustums of several
            boxes rotated in one call).

    Returns:
        (P, 3) float64 points in the frustum frame.
    """
    return _rotate_about_y(points_cam, angle)


def rotate_from_frustum(points_frustum: np.ndarray, angle: float | np.ndarray) -> np.ndarray:
    """Inverse of :func:`rotate_to_frustum`: frustum-frame points back to the camera frame."""
    return _rotate_about_y(points_frustum, -angle)


def _rotate_about_y(points: np.ndarray, angle: float | np.ndarray) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    cos, sin = np.cos(angle), np.sin(angle)
    rotated = points.copy()
    rotated[:, 0] = cos * points[:, 0] - sin * points[:, 2]
    rotated[:, 2] = sin * points[:, 0] + cos * points[:, 2]
    return rotated


def frustum_corners(
    box2d: np.ndarray, intrinsic: np.ndarray, near: float, far: float
) -> np.ndarray:
    """Corners of the frustum of a 2D box between two depths.

    Args:
        box2d: (4,) [x1, y1, x2, y2] pixels.
        intrinsic: (3, 3) camera matrix.
        near, far: depths in metres, ``0 <= near < far`` (near = 0 gives the apex).

    Returns:
        (8, 3) float64 camera-frame corners: the near face (x1, y1), (x2, y1), (x2, y2),
        (x1, y2), then the far face in the same order.
    """
    if not 0 <= near < far:
        raise SianmsError(f"frustum depths must satisfy 0 <= near < far, got {near}, {far}")
    x1, y1, x2, y2 = np.asarray(box2d, dtype=np.float64)
    pixels = np.array([[x1, y1], [x2, y1], [x2, y2], [x1, y2]])
    rays = pixel_rays(pixels, intrinsic)
    return np.concatenate([near * rays, far * rays], axis=0)
