"""Pinhole projection of points and boxes into a camera image.

Camera frame as OpenCV and nuScenes: x right, y down, z forward (depth), metres. Pixel
coordinates (u, v) have their origin at the top-left corner of the image; an image of
size (W, H) spans [0, W] x [0, H].
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np

from sianms_cli.errors import SianmsError
from sianms_cli.geometry.boxes import BOX_EDGES

_MAX_PAIR_SAMPLES = 4_000_000  # bound on the (boxes x samples x boxes) temporary of occlusion_fractions


class BoxVisibility(IntEnum):
    """Visibility levels of the devkit's ``box_in_image`` (same integer values)."""

    ALL = 0
    ANY = 1
    NONE = 2


def view_points(points: np.ndarray, intrinsic: np.ndarray, normalize: bool = True) -> np.ndarray:
    """The devkit's ``view_points`` on row-major points.

    The view matrix is padded into a 4x4 identity, applied to homogeneous points, and
    when ``normalize`` all three output coordinates are divided by the third (depth),
    with no check of its sign: points behind the camera come out mirrored and points
    at depth 0 give inf/nan, as in the devkit.

    Args:
        points: (N, 3) points.
        intrinsic: (3, 3), (3, 4) or (4, 4) view matrix.
        normalize: divide by depth (perspective projection).

    Returns:
        (N, 3) float64; with ``normalize`` the rows are (u, v, 1).
    """
    view = np.asarray(intrinsic, dtype=np.float64)
    if view.ndim != 2 or view.shape[0] > 4 or view.shape[1] > 4:
        raise SianmsError(f"view matrix must be at most 4x4, got shape {view.shape}")
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    viewpad = np.eye(4)
    viewpad[: view.shape[0], : view.shape[1]] = view
    homogeneous = np.concatenate([points, np.ones((len(points), 1))], axis=1)
    mapped = (homogeneous @ viewpad.T)[:, :3]
    if normalize:
        with np.errstate(divide="ignore", invalid="ignore"):
            mapped = mapped / mapped[:, 2:3]
    return mapped


def _pixels(points_cam: np.ndarray, intrinsic: np.ndarray) -> np.ndarray:
    """(..., 3) camera-frame points at positive depth -> (..., 2) pixel coordinates."""
    projected = points_cam @ np.asarray(intrinsic, dtype=np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        return projected[..., :2] / projected[..., 2:3]


def project_boxes_to_image(
    corners_cam: np.ndarray,
    intrinsic: np.ndarray,
    image_size: tuple[float, float],
    near: float = 0.1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """2D boxes of 3D boxes seen by a camera, with truncation by the image border.

    Each box (a convex solid) is first clipped by the near plane ``z = near``: corners
    with ``z >= near`` are kept and every edge crossing the plane contributes its
    intersection point. The extent of the projected points is the unclipped 2D box,
    which is then intersected with the image rectangle [0, W] x [0, H].

    Args:
        corners_cam: (N, 8, 3) box corners in the camera frame (devkit corner order).
        intrinsic: (3, 3) camera matrix.
        image_size: (W, H) in pixels.
        near: near-plane depth, metres, > 0.

    Returns:
        ``(boxes2d, truncation, valid)``:
        boxes2d (N, 4) float64 [x1, y1, x2, y2] clipped to the image;
        truncation (N,) float64 in [0, 1], ``1 - clipped area / unclipped area``;
        valid (N,) bool: some part of the box lies at ``z >= near`` and the clipped box
        has positive area. Invalid rows have boxes2d = 0 and truncation = 1.
    """
    if not near > 0:
        raise SianmsError(f"near plane must be at positive depth, got {near}")
    corners_cam = np.asarray(corners_cam, dtype=np.float64).reshape(-1, 8, 3)
    width, height = float(image_size[0]), float(image_size[1])

    in_front = corners_cam[:, :, 2] >= near
    start = corners_cam[:, BOX_EDGES[:, 0]]
    end = corners_cam[:, BOX_EDGES[:, 1]]
    crossing = in_front[:, BOX_EDGES[:, 0]] != in_front[:, BOX_EDGES[:, 1]]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (near - start[..., 2]) / (end[..., 2] - start[..., 2])
    t = np.where(crossing, t, 0.0)
    intersections = start + t[..., None] * (end - start)
    intersections[..., 2] = np.where(crossing, near, intersections[..., 2])

    candidates = np.concatenate([corners_cam, intersections], axis=1)
    keep = np.concatenate([in_front, crossing], axis=1)
    # Points we do not keep are moved onto the plane so their projection stays finite;
    # they are masked out of the extent below.
    candidates[..., 2] = np.where(keep, candidates[..., 2], near)
    uv = _pixels(candidates, intrinsic)
    u_min = np.where(keep, uv[..., 0], np.inf).min(axis=1)
    v_min = np.where(keep, uv[..., 1], np.inf).min(axis=1)
    u_max = np.where(keep, uv[..., 0], -np.inf).max(axis=1)
    v_max = np.where(keep, uv[..., 1], -np.inf).max(axis=1)

    any_front = in_front.any(axis=1)
    x1, x2 = np.clip(u_min, 0.0, width), np.clip(u_max, 0.0, width)
    y1, y2 = np.clip(v_min, 0.0, height), np.clip(v_max, 0.0, height)
    clipped_area = np.where(any_front, np.maximum(x2 - x1, 0) * np.maximum(y2 - y1, 0), 0.0)
    valid = any_front & (clipped_area > 0)
    unclipped_area = np.where(valid, (u_max - u_min) * (v_max - v_min), 1.0)
    truncation = np.where(valid, 1.0 - clipped_area / unclipped_area, 1.0)
    boxes2d = np.where(valid[:, None], np.stack([x1, y1, x2, y2], axis=1), 0.0)
    return boxes2d, np.clip(truncation, 0.0, 1.0), valid


def occlusion_fractions(
    boxes2d: np.ndarray, distance: np.ndarray, samples_per_side: int = 12
) -> np.ndarray:
    """Share of each 2D box covered by the 2D boxes of nearer objects.

    Each box is sampled on a ``samples_per_side`` x ``samples_per_side`` grid of points at
    the centres of equal cells; a point is covered when it lies inside (bounds inclusive)
    the box of an object with a strictly smaller ``distance``. The 2D box of a projected
    cuboid is larger than its silhouette, so this slightly over-estimates occlusion (a
    conservative figure); occluders without a box (buildings) are ignored.

    Args:
        boxes2d: (N, 4) [x1, y1, x2, y2] pixels.
        distance: (N,) distances from the camera, metres.
        samples_per_side: grid resolution per box.

    Returns:
        (N,) float64 in [0, 1]; 0 for N = 0 or 1.
    """
    boxes2d = np.asarray(boxes2d, dtype=np.float64).reshape(-1, 4)
    distance = np.asarray(distance, dtype=np.float64).reshape(-1)
    count = len(boxes2d)
    if count < 2:
        return np.zeros(count)
    steps = (np.arange(samples_per_side) + 0.5) / samples_per_side
    width = boxes2d[:, 2] - boxes2d[:, 0]
    height = boxes2d[:, 3] - boxes2d[:, 1]
    xs = boxes2d[:, 0, None] + steps[None, :] * width[:, None]  # (N, k)
    ys = boxes2d[:, 1, None] + steps[None, :] * height[:, None]
    px = np.repeat(xs, samples_per_side, axis=1)  # (N, k*k) x varies slowest
    py = np.tile(ys, (1, samples_per_side))
    nearer = distance[None, :] < distance[:, None]  # (N, N): j nearer than i
    occlusion = np.zeros(count)
    chunk = max(1, _MAX_PAIR_SAMPLES // max(count * samples_per_side**2, 1))
    for start in range(0, count, chunk):
        sl = slice(start, start + chunk)
        inside = (
            (px[sl, :, None] >= boxes2d[None, None, :, 0])
            & (px[sl, :, None] <= boxes2d[None, None, :, 2])
            & (py[sl, :, None] >= boxes2d[None, None, :, 1])
            & (py[sl, :, None] <= boxes2d[None, None, :, 3])
        )
        covered = (inside & nearer[sl, None, :]).any(axis=2)
        occlusion[sl] = covered.mean(axis=1)
    return occlusion


def box_in_image(
    corners_cam: np.ndarray,
    intrinsic: np.ndarray,
    image_size: tuple[float, float],
    vis_level: BoxVisibility | int | str = BoxVisibility.ANY,
) -> np.ndarray:
    """The devkit's ``box_in_image`` for many boxes.

    A corner is visible when it projects with 0 < u < W and 0 < v < H (strict) and its
    depth is > 1 m; it is in front when its depth is > 0.1 m. ALL: every corner visible
    and in front. ANY: at least one corner visible and every corner in front (a box
    crossing the image plane is rejected). NONE: always true.

    Args:
        corners_cam: (N, 8, 3) box corners in the camera frame.
        intrinsic: (3, 3) camera matrix.
        image_size: (W, H) in pixels.
        vis_level: a :class:`BoxVisibility`, its integer value or its name ("any", ...).

    Returns:
        (N,) bool.
    """
    level = _visibility(vis_level)
    corners_cam = np.asarray(corners_cam, dtype=np.float64).reshape(-1, 8, 3)
    if level is BoxVisibility.NONE:
        return np.ones(len(corners_cam), dtype=bool)
    uv = view_points(corners_cam.reshape(-1, 3), intrinsic, normalize=True)[:, :2]
    uv = uv.reshape(-1, 8, 2)
    depth = corners_cam[:, :, 2]
    visible = (
        (uv[..., 0] > 0)
        & (uv[..., 0] < image_size[0])
        & (uv[..., 1] < image_size[1])
        & (uv[..., 1] > 0)
        & (depth > 1)
    )
    all_in_front = (depth > 0.1).all(axis=1)
    if level is BoxVisibility.ALL:
        return np.all(visible, axis=1) & all_in_front
    return np.any(visible, axis=1) & all_in_front


def _visibility(vis_level: BoxVisibility | int | str) -> BoxVisibility:
    if isinstance(vis_level, str):
        try:
            return BoxVisibility[vis_level.upper()]
        except KeyError:
            pass
    else:
        try:
            return BoxVisibility(vis_level)
        except ValueError:
            pass
    names = ", ".join(level.name.lower() for level in BoxVisibility)
    raise SianmsError(f"unknown box visibility level {vis_level!r}; expected one of {names}")
