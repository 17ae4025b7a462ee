"""3-D IoU of oriented boxes in the Frustum PointNets camera convention, vectorised over box pairs.

A box is ``center (N, 3)``, ``lwh (N, 3)`` ordered (l, w, h) as F-PointNets (not nuScenes'
w, l, h) and ``heading (N,)``, all in a camera or frustum frame (x right, y down, z forward):
the length axis is R_y(heading) applied to +x, i.e. (cos h, 0, -sin h) (docs/methods.md#box-corners).
The height runs along y, so the bird's-eye view is the (x, z) plane.

Intersection volume = rotated BEV intersection area x overlap of the y intervals. The BEV
intersection of two rectangles is Sutherland–Hodgman: rectangle A clipped by the four inner
half-planes of rectangle B, all pairs at once; a convex polygon clipped by a
half-plane gains at most one vertex, so 4 vertices grow to at most 8.
"""

from __future__ import annotations

import numpy as np

from sianms_cli.geometry.clip import polygon_areas

# Corner signs along (length, width) in counter-clockwise order in the (x, z) plane.
_BEV_SIGNS = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])


def bev_corners(center: np.ndarray, lwh: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """(N, 4, 2) BEV corners (x, z) of boxes, counter-clockwise in the (x, z) plane.

    The length axis (cos h, -sin h) and the width axis (sin h, cos h) form a right-handed pair
    in (x, z), so the local order (+,+), (-,+), (-,-), (+,-) stays counter-clockwise.
    """
    center = np.asarray(center, dtype=np.float64).reshape(-1, 3)
    lwh = np.asarray(lwh, dtype=np.float64).reshape(-1, 3)
    heading = np.asarray(heading, dtype=np.float64).reshape(-1)
    cos, sin = np.cos(heading), np.sin(heading)
    length_axis = np.stack([cos, -sin], axis=1)
    width_axis = np.stack([sin, cos], axis=1)
    local = _BEV_SIGNS[None] * 0.5 * lwh[:, None, :2]
    return (center[:, None, [0, 2]] + local[..., :1] * length_axis[:, None, :]
            + local[..., 1:] * width_axis[:, None, :])


def rotated_intersection_area(corners_a: np.ndarray, corners_b: np.ndarray) -> np.ndarray:
    """(N,) area of the intersection of each pair of counter-clockwise convex quadrilaterals.

    Args:
        corners_a, corners_b: (N, 4, 2) counter-clockwise corners.
    """
    polygons = np.concatenate([corners_a, np.zeros_like(corners_a)], axis=1)  # room for 8 vertices
    counts = np.full(len(corners_a), 4, dtype=np.int64)
    for edge in range(4):
        start, end = corners_b[:, edge], corners_b[:, (edge + 1) % 4]
        polygons, counts = _clip_by_edge(polygons, counts, start, end)
    return polygon_areas(polygons, counts)


def _clip_by_edge(polygons: np.ndarray, counts: np.ndarray, start: np.ndarray,
                  end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One Sutherland–Hodgman pass: keep the part of each polygon left of (or on) start -> end.

    Every vertex emits itself when inside and the crossing point when its edge to the next
    vertex changes sides; the emitted points are compacted in order to the front and cut to
    the array's width (a convex polygon never needs more than 8 here).
    """
    size = polygons.shape[1]
    direction = end - start
    side = (direction[:, None, 0] * (polygons[..., 1] - start[:, None, 1])
            - direction[:, None, 1] * (polygons[..., 0] - start[:, None, 0]))
    index = np.arange(size)
    alive = index < counts[:, None]
    following_index = np.where(index + 1 < counts[:, None], index + 1, 0)
    following = np.take_along_axis(polygons, following_index[..., None], axis=1)
    side_following = np.take_along_axis(side, following_index, axis=1)
    kept = alive & (side >= 0)
    crossing = alive & (kept != (side_following >= 0))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(crossing, side / (side - side_following), 0.0)
    crossings = polygons + t[..., None] * (following - polygons)
    emitted = np.stack([polygons, crossings], axis=2).reshape(len(polygons), 2 * size, 2)
    valid = np.stack([kept, crossing], axis=2).reshape(len(polygons), 2 * size)
    position = np.cumsum(valid, axis=1) - 1
    rows, columns = np.nonzero(valid & (position < size))
    compacted = np.zeros_like(polygons)
    compacted[rows, position[rows, columns]] = emitted[rows, columns]
    return compacted, np.minimum(valid.sum(axis=1), size)


def box_iou3d(center_a: np.ndarray, lwh_a: np.ndarray, heading_a: np.ndarray, center_b: np.ndarray,
              lwh_b: np.ndarray, heading_b: np.ndarray) -> np.ndarray:
    """(N,) float64 3-D IoU of box a[i] with box b[i] (aligned pairs, not all pairs).

    Boxes as the module docstring (camera/frustum frame, (l, w, h), F-PointNets heading).
    Zero-volume pairs give 0 (the union is clamped to 1e-12 m³).
    """
    center_a = np.asarray(center_a, dtype=np.float64).reshape(-1, 3)
    center_b = np.asarray(center_b, dtype=np.float64).reshape(-1, 3)
    lwh_a = np.asarray(lwh_a, dtype=np.float64).reshape(-1, 3)
    lwh_b = np.asarray(lwh_b, dtype=np.float64).reshape(-1, 3)
    area = rotated_intersection_area(bev_corners(center_a, lwh_a, heading_a), bev_corners(center_b, lwh_b, heading_b))
    low = np.maximum(center_a[:, 1] - 0.5 * lwh_a[:, 2], center_b[:, 1] - 0.5 * lwh_b[:, 2])
    high = np.minimum(center_a[:, 1] + 0.5 * lwh_a[:, 2], center_b[:, 1] + 0.5 * lwh_b[:, 2])
    intersection = np.maximum(area, 0.0) * np.maximum(high - low, 0.0)
    union = lwh_a.prod(axis=1) + lwh_b.prod(axis=1) - intersection
    return intersection / np.maximum(union, 1e-12)
