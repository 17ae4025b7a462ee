"""Convex hulls of small point sets clipped to an image rectangle, vectorised over many sets.

This is the devkit's 2-D export rule (``export_2d_annotations_as_json.py``
``post_process_coords``: the shapely convex hull of the projected box corners intersected
with the image canvas) without shapely and without a Python loop per box: each set of at
most K points becomes its hull (angular sort about the centroid, then reflex vertices
dropped until none is left), which Sutherland–Hodgman clips against the four image edges.
Polygons travel as ``(M, K, 2)`` vertex arrays with ``(M,)`` vertex counts; the first
``count`` vertices of a row are its polygon, counter-clockwise in (u, v).
"""

from __future__ import annotations

import numpy as np


def convex_hulls(points: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The convex hull of the kept points of each set, as a counter-clockwise polygon.

    Sorting by angle about the centroid gives a star-shaped polygon holding every hull vertex.
    A strictly reflex vertex of it lies inside the triangle of the centroid and its two
    neighbours (their angular gap is under 180° while the centroid is interior), so it is
    never a hull vertex: dropping all of them at once, until none is left, leaves the hull.
    Collinear and repeated vertices may stay; they change neither the area nor the extent.

    Args:
        points: (M, K, 2) coordinates.
        keep: (M, K) bool, the points of each set.

    Returns:
        ``(polygons (M, K, 2), counts (M,) int64)``. A set of fewer than 3 points, or of
        collinear points, gives a polygon of zero area.
    """
    keep = np.asarray(keep, dtype=bool)
    points = np.where(keep[..., None], np.asarray(points, dtype=np.float64), 0.0)
    counts = keep.sum(axis=1)
    center = points.sum(axis=1) / np.maximum(counts, 1)[:, None]
    offset = points - center[:, None, :]
    angle = np.where(keep, np.arctan2(offset[..., 1], offset[..., 0]), np.inf)
    order = np.argsort(angle, axis=1, kind="stable")
    polygons = np.take_along_axis(points, order[..., None], axis=1)
    active = np.flatnonzero(counts >= 4)  # a triangle is its own hull
    for _ in range(points.shape[1]):
        part, part_counts = polygons[active], counts[active]
        previous, following = _neighbours(part, part_counts)
        alive = np.arange(points.shape[1]) < part_counts[:, None]
        reflex = alive & (_cross(part - previous, following - part) < 0)
        changed = reflex.any(axis=1)
        active, part, alive = active[changed], part[changed], alive[changed] & ~reflex[changed]
        if len(active) == 0:
            break
        polygons[active], counts[active] = _compact(part, alive), alive.sum(axis=1)
    return polygons, counts


def clip_to_rectangles(polygons: np.ndarray, counts: np.ndarray, width: np.ndarray,
                       height: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sutherland–Hodgman: each convex polygon intersected with its rectangle [0, W] x [0, H].

    Each of the four edges adds at most one vertex to a convex polygon, so K grows to K + 4.

    Args:
        polygons: (M, K, 2) convex counter-clockwise polygons, ``counts`` (M,) vertices each.
        width, height: (M,) or scalar rectangle sizes.

    Returns:
        ``(polygons (M, K + 4, 2), counts (M,))``; count 0 where nothing is left.
    """
    width = np.broadcast_to(np.asarray(width, dtype=np.float64), counts.shape)
    height = np.broadcast_to(np.asarray(height, dtype=np.float64), counts.shape)
    zero = np.zeros(counts.shape)
    # (axis, sign, offset): the signed distance inside the edge is sign * coordinate + offset.
    for axis, sign, offset in ((0, 1.0, zero), (0, -1.0, width), (1, 1.0, zero), (1, -1.0, height)):
        polygons, counts = _clip_half_plane(polygons, counts, axis, sign, offset)
    return polygons, counts


def polygon_areas(polygons: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """(M,) shoelace areas of counter-clockwise polygons (0 for fewer than 3 vertices)."""
    _, following = _neighbours(polygons, counts)
    alive = np.arange(polygons.shape[1]) < counts[:, None]
    return 0.5 * np.where(alive, _cross(polygons, following), 0.0).sum(axis=1)


def polygon_extents(polygons: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """(M, 4) [u_min, v_min, u_max, v_max] of each polygon; NaN where it has no vertex."""
    alive = (np.arange(polygons.shape[1]) < counts[:, None])[..., None]
    low = np.where(alive, polygons, np.inf).min(axis=1, initial=np.inf)
    high = np.where(alive, polygons, -np.inf).max(axis=1, initial=-np.inf)
    extents = np.concatenate([low, high], axis=1)
    return np.where((counts > 0)[:, None], extents, np.nan)


def hull_in_rectangle(points: np.ndarray, keep: np.ndarray, width: np.ndarray,
                      height: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The devkit's ``post_process_coords``: extent and area of hull(kept points) ∩ image.

    Args:
        points: (M, K, 2) projected points (pixels).
        keep: (M, K) bool, the points to use (the devkit keeps the corners in front, z > 0).
        width, height: (M,) or scalar image sizes.

    Returns:
        ``(extents (M, 4) [u_min, v_min, u_max, v_max], areas (M,))``. A set yields an image
        box when its area is positive; the devkit would fail on the zero-area cases (a point
        or a segment has no ``exterior``), so none of them is a box.
    """
    hulls, counts = convex_hulls(points, keep)
    clipped, counts = clip_to_rectangles(hulls, counts, width, height)
    return polygon_extents(clipped, counts), polygon_areas(clipped, counts)


def hull_meets_rectangle(points: np.ndarray, keep: np.ndarray, width: np.ndarray,
                         height: np.ndarray) -> np.ndarray:
    """(M,) bool: hull(kept points) ∩ [0, W] x [0, H] has positive area (the devkit yields a box).

    The same answer as ``hull_in_rectangle(...)[1] > 0``, faster: a set whose points all lie
    inside the rectangle needs no clipping, and its hull has positive area unless its points
    are collinear; only the sets that cross an edge are clipped. (On points collinear only to
    within rounding both answers are rounding, and may differ.)
    """
    keep = np.asarray(keep, dtype=bool)
    points = np.where(keep[..., None], np.asarray(points, dtype=np.float64), 0.0)
    width = np.broadcast_to(np.asarray(width, dtype=np.float64), keep.shape[:1])
    height = np.broadcast_to(np.asarray(height, dtype=np.float64), keep.shape[:1])
    low = np.where(keep[..., None], points, np.inf).min(axis=1, initial=np.inf)
    high = np.where(keep[..., None], points, -np.inf).max(axis=1, initial=-np.inf)
    inside = (low >= 0).all(axis=1) & (high[:, 0] <= width) & (high[:, 1] <= height)
    meets = inside & ~_collinear(points, keep)
    crossing = np.flatnonzero(~inside & (keep.sum(axis=1) >= 3))
    _, areas = hull_in_rectangle(points[crossing], keep[crossing], width[crossing], height[crossing])
    meets[crossing] = areas > 0
    return meets


def _collinear(points: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """(M,) bool: the kept points of each set lie on one line (or there are fewer than 3)."""
    first = np.take_along_axis(points, np.argmax(keep, axis=1)[:, None, None], axis=1)
    offset = np.where(keep[..., None], points - first, 0.0)
    farthest = np.take_along_axis(offset, np.argmax(np.abs(offset).sum(axis=2), axis=1)[:, None, None], axis=1)
    return ~(_cross(offset, farthest) != 0).any(axis=1)


def _clip_half_plane(polygons: np.ndarray, counts: np.ndarray, axis: int, sign: float,
                     offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One Sutherland–Hodgman pass: keep where ``sign * coordinate[axis] + offset >= 0``.

    Only polygons with a vertex outside are touched. Every vertex emits itself when inside
    and the crossing point when its edge to the next vertex changes sides; the emitted points
    are compacted in order to the front. A crossing point lies exactly on the edge (no
    rounding past the image border). The polygons gain one vertex slot.
    """
    inside = sign * polygons[..., axis] + offset[:, None]
    alive = np.arange(polygons.shape[1]) < counts[:, None]
    polygons = np.concatenate([polygons, np.zeros_like(polygons[:, :1])], axis=1)
    counts = counts.copy()
    cut = np.flatnonzero((alive & (inside < 0)).any(axis=1))
    part, part_counts, part_inside = polygons[cut, :-1], counts[cut], inside[cut]
    following_index = _following_index(part_counts, part.shape[1])
    following = np.take_along_axis(part, following_index[..., None], axis=1)
    inside_following = np.take_along_axis(part_inside, following_index, axis=1)
    kept = alive[cut] & (part_inside >= 0)
    crossing = alive[cut] & (kept != (inside_following >= 0))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(crossing, part_inside / (part_inside - inside_following), 0.0)
    crossings = part + t[..., None] * (following - part)
    crossings[..., axis] = (-sign * offset[cut])[:, None]
    emitted = np.stack([part, crossings], axis=2).reshape(len(cut), 2 * part.shape[1], 2)
    valid = np.stack([kept, crossing], axis=2).reshape(len(cut), 2 * part.shape[1])
    polygons[cut] = _compact(emitted, valid)[:, : polygons.shape[1]]
    counts[cut] = np.minimum(valid.sum(axis=1), polygons.shape[1])
    return polygons, counts


def _compact(points: np.ndarray, alive: np.ndarray) -> np.ndarray:
    """The alive points of each row moved to its front, in order (the rest zero)."""
    position = np.cumsum(alive, axis=1) - 1
    rows, columns = np.nonzero(alive)
    compacted = np.zeros_like(points)
    compacted[rows, position[rows, columns]] = points[rows, columns]
    return compacted


def _following_index(counts: np.ndarray, size: int) -> np.ndarray:
    """(M, size) index of the next vertex of each polygon, wrapping at its count."""
    index = np.arange(size) + 1
    return np.where(index < counts[:, None], index, 0)


def _neighbours(polygons: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The previous and the next vertex of every vertex, cyclically within each polygon."""
    index = np.arange(polygons.shape[1])
    previous_index = np.where(index >= 1, index - 1, np.maximum(counts - 1, 0)[:, None])
    following_index = _following_index(counts, polygons.shape[1])
    return (np.take_along_axis(polygons, previous_index[..., None], axis=1),
            np.take_along_axis(polygons, following_index[..., None], axis=1))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """z of the 2-D cross product of (..., 2) vectors."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
