"""Greedy per-class BEV non-maximum suppression: axis-aligned, rotated and circle (docs/methods.md#nms-variants).

All three take boxes as arrays in the nuScenes global frame (:mod:`sianms_cli.geometry.bev`:
``centers (N, 2)`` metres, ``sizes (N, 2)`` (width, length) metres, ``yaw (N,)`` radians of
the length axis from +x, counter-clockwise), ``scores (N,)`` and ``labels (N,)`` (any values
that compare equal within a class), and return the kept indices as an ``(K,) int64`` array
in descending score order. Equal scores are visited lower index first (a stable sort), so
the result is deterministic. Boxes of different labels never suppress each other. A kept box
suppresses every later box of its class whose BEV IoU with it is *above* the threshold
(strict, as torchvision ``ops.nms``), or for circle NMS whose centre lies within its radius.

Only candidate pairs are tested: boxes are bucketed into grid cells at least as wide as the
largest reach (the sum of two half-diagonals, or the circle radius), so a box meets only the
boxes of its class in the 3 x 3 cells around it, and a rotated pair is clipped only when its
separating-axis bound could pass the threshold. The loop is compiled with numba
(``cache=True`` keeps the machine code next to this file, so only the first call after an
install compiles); numba is imported with this module, which only ``sianms eval`` loads, so
``sianms --help`` stays fast.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sianms_cli.errors import SianmsError
from sianms_cli.geometry.bev import axis_aligned_rectangles, check_boxes

# Effective circle-NMS radii in metres per nuScenes detection class. CenterPoint's nuScenes
# config (`configs/nusc/pp/nusc_centerpoint_pp_02voxel_two_pfn_10sweep_circular_nms.py`,
# MM3D `centerpoint_voxel01_second_secfpn_nus.py`) sets min_radius = [4, 12, 10, 1, 0.85,
# 0.175] for the task heads [car], [truck, construction_vehicle], [bus, trailer], [barrier],
# [motorcycle, bicycle], [pedestrian, traffic_cone], and `circle_nms` compares them with the
# *squared* centre distance: "4" for cars is a 2.0 m radius, not 4 m (docs/methods.md#circle-nms).
CIRCLE_RADIUS_M: dict[str, float] = {
    "car": math.sqrt(4.0),
    "truck": math.sqrt(12.0),
    "construction_vehicle": math.sqrt(12.0),
    "bus": math.sqrt(10.0),
    "trailer": math.sqrt(10.0),
    "barrier": math.sqrt(1.0),
    "motorcycle": math.sqrt(0.85),
    "bicycle": math.sqrt(0.85),
    "pedestrian": math.sqrt(0.175),
    "traffic_cone": math.sqrt(0.175),
}

# What the compiled loop tests between a kept box i and a later box j (columns of `data`).
_CIRCLE = 0  # (x, y, radius): suppress when |c_i - c_j| <= radius_i
_RECTANGLE = 1  # (x_min, y_min, x_max, y_max): suppress when axis-aligned IoU > threshold
_ROTATED = 2  # (x, y, width, length, cos yaw, sin yaw, half-diagonal): rotated IoU > threshold

# Grid cells per axis at most, so a cell key (label, column, row) fits in an int64.
_MAX_CELLS = 2**16


def axis_nms(centers: np.ndarray, sizes: np.ndarray, yaw: np.ndarray, scores: np.ndarray, labels: np.ndarray,
             iou_threshold: float, mode: str = "ignore-yaw") -> np.ndarray:
    """(K,) int64 kept indices of greedy per-class NMS on axis-aligned BEV IoU.

    Args:
        centers: (N, 2) metres; sizes: (N, 2) (width, length) metres; yaw: (N,) radians.
        scores: (N,) finite; labels: (N,) class of each box.
        iou_threshold: in [0, 1]; a box is suppressed when its IoU is above it.
        mode: which axis-aligned box stands for a rotated one, one of
            :data:`sianms_cli.geometry.bev.AXIS_MODES` (``ignore-yaw``, ``nearest-bev``,
            ``enclosing``; the paper's baseline is axis-aligned without saying which).
    """
    centers, sizes, yaw = check_boxes(centers, sizes, yaw)
    rectangles = axis_aligned_rectangles(centers, sizes, yaw, mode)  # each centred on its box
    half_diagonal = 0.5 * np.hypot(rectangles[:, 2] - rectangles[:, 0], rectangles[:, 3] - rectangles[:, 1])
    return _greedy_nms(rectangles, centers, 2.0 * half_diagonal, scores, labels, _RECTANGLE,
                       _check_threshold(iou_threshold))


def rotated_nms(centers: np.ndarray, sizes: np.ndarray, yaw: np.ndarray, scores: np.ndarray, labels: np.ndarray,
                iou_threshold: float) -> np.ndarray:
    """(K,) int64 kept indices of greedy per-class NMS on exact rotated BEV IoU.

    Arguments as :func:`axis_nms`. The IoU is the one of
    :func:`sianms_cli.geometry.bev.rotated_iou_pairs` (Sutherland–Hodgman, union floor 1e-8),
    equal to it up to rounding; a box of zero area suppresses nothing and is never suppressed.
    """
    centers, sizes, yaw = check_boxes(centers, sizes, yaw)
    half_diagonal = 0.5 * np.hypot(sizes[:, 0], sizes[:, 1])
    data = np.column_stack([centers, sizes, np.cos(yaw), np.sin(yaw), half_diagonal])
    return _greedy_nms(data, centers, 2.0 * half_diagonal, scores, labels, _ROTATED, _check_threshold(iou_threshold))


def circle_nms(centers: np.ndarray, scores: np.ndarray, labels: np.ndarray, radius: float | np.ndarray) -> np.ndarray:
    """(K,) int64 kept indices of greedy per-class circle NMS on BEV centres (CenterPoint).

    A kept box suppresses every later box of its class whose centre lies within ``radius``
    metres of its own (distance <= radius, as CenterPoint's ``<=`` on squared distances).

    Args:
        centers: (N, 2) metres. scores: (N,) finite. labels: (N,) class of each box.
        radius: metres, not squared metres; a scalar, or (N,) per box (the kept box's own
            radius applies), e.g. ``np.array([CIRCLE_RADIUS_M[name] for name in names])[labels]``.
    """
    centers = np.asarray(centers, dtype=np.float64)
    if centers.ndim != 2 or centers.shape[1] != 2 or not np.isfinite(centers).all():
        raise SianmsError(f"circle_nms needs finite centers of shape (N, 2), got shape {centers.shape}")
    radius = np.asarray(radius, dtype=np.float64)
    if radius.ndim == 0:
        radius = np.full(len(centers), float(radius))
    if radius.shape != (len(centers),) or not (np.isfinite(radius).all() and (radius >= 0).all()):
        raise SianmsError(f"circle_nms radius must be finite metres >= 0, a scalar or one per box ({len(centers)}), "
                          f"got shape {radius.shape}")
    return _greedy_nms(np.column_stack([centers, radius]), centers, radius, scores, labels, _CIRCLE, 0.0)


def _check_threshold(iou_threshold: float) -> float:
    threshold = float(iou_threshold)
    if not 0.0 <= threshold <= 1.0:
        raise SianmsError(f"NMS IoU threshold must be in [0, 1], got {iou_threshold}")
    return threshold


def _greedy_nms(data: np.ndarray, centers: np.ndarray, reach: np.ndarray, scores: np.ndarray, labels: np.ndarray,
                kind: int, threshold: float) -> np.ndarray:
    """Validate scores and labels, bucket the boxes, and run the compiled greedy loop.

    Args:
        data: (N, C) float64 per-box columns of ``kind``; centers: (N, 2) where boxes sit.
        reach: (N,) the farthest centre distance at which box i can suppress another box.
    """
    scores = np.asarray(scores, dtype=np.float64)
    labels = np.asarray(labels)
    count = len(centers)
    if scores.shape != (count,) or labels.shape != (count,):
        raise SianmsError(f"NMS needs one score and one label per box ({count}), got shapes {scores.shape} and "
                          f"{labels.shape}")
    if not np.isfinite(scores).all():
        raise SianmsError("NMS scores must be finite (a score is NaN or infinite)")
    if count == 0:
        return np.zeros(0, dtype=np.int64)
    order = np.argsort(-scores, kind="stable")  # descending; equal scores lower index first
    keys, rows = _cell_keys(centers, reach, np.unique(labels, return_inverse=True)[1].reshape(-1))
    # The loop works on the boxes sorted by cell, so the boxes of one cell sit side by side
    # in memory; `visit` is the score order in those positions.
    by_key = np.argsort(keys, kind="stable")
    position = np.empty(count, dtype=np.int64)
    position[by_key] = np.arange(count)
    kept = _greedy(position[order], keys[by_key], rows, np.ascontiguousarray(data[by_key]), kind, threshold)
    return by_key[kept]


def _cell_keys(centers: np.ndarray, reach: np.ndarray, classes: np.ndarray) -> tuple[np.ndarray, int]:
    """(N,) int64 grid-cell keys and the key stride of one column.

    Cells are at least ``max(reach)`` wide, so every box a box can suppress lies in the 3 x 3
    cells around it. Columns and rows start at 1 and a class's block has two spare columns
    and rows, so ``key + dx * rows + dy`` for dx, dy in {-1, 0, 1} never reaches another class.
    """
    low = centers.min(axis=0)
    span = float((centers.max(axis=0) - low).max())
    size = max(float(reach.max()), span / (_MAX_CELLS - 1), 1e-9)
    cell = np.floor((centers - low) / size).astype(np.int64) + 1
    columns, rows = int(cell[:, 0].max()) + 2, int(cell[:, 1].max()) + 2
    return (classes.astype(np.int64) * columns + cell[:, 0]) * rows + cell[:, 1], rows


@numba.njit(cache=True)
def _greedy(visit, keys, rows, data, kind, threshold):
    """Kept positions, in visiting order, of greedy NMS over the candidate pairs of the grid.

    Args:
        visit: (N,) positions in score order. keys: (N,) sorted cell keys of the positions.
        rows: key stride of one grid column. data: (N, C) per-position columns of ``kind``.
    """
    count = len(visit)
    rank = np.empty(count, dtype=np.int64)
    for step in range(count):  # a loop: numba compiles fancy-index assignment for seconds
        rank[visit[step]] = step
    suppressed = np.zeros(count, dtype=np.bool_)
    kept = np.empty(count, dtype=np.int64)
    buffers = np.empty((4, 8))  # Sutherland–Hodgman vertices: x, y, and the next pass's x, y
    kept_count = 0
    for i in visit:
        if suppressed[i]:
            continue
        kept[kept_count] = i
        kept_count += 1
        for dx in range(-1, 2):  # the three cells (dy = -1, 0, 1) of a column have consecutive keys
            key_column = keys[i] + dx * rows
            for j in range(_lower_bound(keys, key_column - 1), _lower_bound(keys, key_column + 2)):
                if suppressed[j] or rank[j] <= rank[i]:
                    continue
                if _suppresses(data, i, j, kind, threshold, buffers):
                    suppressed[j] = True
    return kept[:kept_count]


@numba.njit(cache=True)
def _lower_bound(keys, value):
    """The first position whose key is >= value in the sorted keys (np.searchsorted, which
    takes numba seconds longer to compile)."""
    low, high = 0, len(keys)
    while low < high:
        middle = (low + high) // 2
        if keys[middle] < value:
            low = middle + 1
        else:
            high = middle
    return low


@numba.njit(cache=True)
def _suppresses(data, i, j, kind, threshold, buffers):
    """Whether kept box i suppresses box j (see the kinds' comments)."""
    dx = data[j, 0] - data[i, 0]
    dy = data[j, 1] - data[i, 1]
    if kind == _CIRCLE:
        return dx * dx + dy * dy <= data[i, 2] * data[i, 2]
    if kind == _RECTANGLE:
        return _rectangle_iou(data[i], data[j]) > threshold
    reach = data[i, 6] + data[j, 6]
    if dx * dx + dy * dy > reach * reach:  # farther apart than the half-diagonals: disjoint
        return False
    return _rotated_suppresses(data[i], data[j], threshold, buffers)


@numba.njit(cache=True)
def _rectangle_iou(a, b):
    """IoU of two (x_min, y_min, x_max, y_max) rectangles, union floor 1e-8."""
    width = min(a[2], b[2]) - max(a[0], b[0])
    height = min(a[3], b[3]) - max(a[1], b[1])
    intersection = max(width, 0.0) * max(height, 0.0)
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - intersection
    return intersection / max(union, 1e-8)


@numba.njit(cache=True)
def _rotated_suppresses(a, b, threshold, buffers):
    """Whether the rotated BEV IoU of boxes a and b (rows of ``_ROTATED`` data) is above the threshold.

    Works in a's own frame, where a is the rectangle |x| <= length/2, |y| <= width/2 and
    global coordinates (kilometres) cost no precision. Most candidate pairs are near misses:
    the overlap of each rectangle with the other's bounding rectangle in its own frame bounds
    the intersection from above (and is 0 for a gap along an edge normal, the exact
    separating-axis test), so only pairs whose bound could pass the threshold are clipped.
    The 1e-9 margin keeps rounding in the bound from ever skipping a pair clipping would pass.
    """
    dx, dy = b[0] - a[0], b[1] - a[1]
    center_x, center_y = dx * a[4] + dy * a[5], -dx * a[5] + dy * a[4]
    cos_b, sin_b = b[4] * a[4] + b[5] * a[5], b[5] * a[4] - b[4] * a[5]  # of yaw_b - yaw_a
    along_b, across_b = center_x * cos_b + center_y * sin_b, -center_x * sin_b + center_y * cos_b
    cos_abs, sin_abs = abs(cos_b), abs(sin_b)
    length_a, width_a, length_b, width_b = 0.5 * a[3], 0.5 * a[2], 0.5 * b[3], 0.5 * b[2]
    area_a, area_b = a[2] * a[3], b[2] * b[3]
    bound = min(_overlap_area(center_x, center_y, length_a, width_a, length_b * cos_abs + width_b * sin_abs,
                              length_b * sin_abs + width_b * cos_abs),
                _overlap_area(along_b, across_b, length_b, width_b, length_a * cos_abs + width_a * sin_abs,
                              length_a * sin_abs + width_a * cos_abs))
    if bound <= 0.0 or bound / max(area_a + area_b - bound, 1e-8) < threshold - 1e-9:
        return False
    twice_area = _clipped_twice_area(center_x, center_y, cos_b, sin_b, length_a, width_a, length_b, width_b, buffers)
    # Clipping by a zero-size box leaves rounding dust, which must not pass threshold 0.
    intersection = max(0.5 * twice_area, 0.0) if area_a > 0.0 and area_b > 0.0 else 0.0
    return intersection / max(area_a + area_b - intersection, 1e-8) > threshold


@numba.njit(cache=True)
def _overlap_area(offset_x, offset_y, half_x, half_y, other_half_x, other_half_y):
    """Overlap area of the centred rectangle (±half_x, ±half_y) and the one at the offset."""
    width = min(half_x, offset_x + other_half_x) - max(-half_x, offset_x - other_half_x)
    height = min(half_y, offset_y + other_half_y) - max(-half_y, offset_y - other_half_y)
    return max(width, 0.0) * max(height, 0.0)


@numba.njit(cache=True)
def _clipped_twice_area(center_x, center_y, cos_b, sin_b, length_a, width_a, length_b, width_b,
                        buffers):
    """Twice the area of rectangle b clipped to the centred rectangle |x| <= length_a, |y| <= width_a.

    Sutherland–Hodgman: b's corners (centre, length axis (cos_b, sin_b), half-sizes
    length_b, width_b) are clipped by the four half-planes, then the shoelace. ``buffers``
    (4, 8) holds the vertices (x, y) and the next pass's.
    """
    xs, ys, next_xs, next_ys = buffers[0], buffers[1], buffers[2], buffers[3]
    for corner in range(4):  # counter-clockwise from front-left, as bev_corners
        along = length_b if corner == 0 or corner == 3 else -length_b
        across = width_b if corner < 2 else -width_b
        xs[corner] = center_x + along * cos_b - across * sin_b
        ys[corner] = center_y + along * sin_b + across * cos_b
    count = 4
    for plane in range(4):  # x <= l/2, -x <= l/2, y <= w/2, -y <= w/2
        limit = length_a if plane < 2 else width_a
        sign = 1.0 if plane % 2 == 0 else -1.0
        coordinates = xs if plane < 2 else ys
        emitted = 0
        for k in range(count):
            following = k + 1 if k + 1 < count else 0
            inside, inside_next = limit - sign * coordinates[k], limit - sign * coordinates[following]
            if inside >= 0.0 and emitted < 8:
                next_xs[emitted], next_ys[emitted] = xs[k], ys[k]
                emitted += 1
            # Opposite signs where crossing, so the denominator is never 0; a convex result
            # has at most 8 vertices, the guard only bounds rounding's extra ones.
            if (inside >= 0.0) != (inside_next >= 0.0) and emitted < 8:
                t = inside / (inside - inside_next)
                next_xs[emitted] = xs[k] + t * (xs[following] - xs[k])
                next_ys[emitted] = ys[k] + t * (ys[following] - ys[k])
                emitted += 1
        for k in range(emitted):
            xs[k], ys[k] = next_xs[k], next_ys[k]
        count = emitted
    twice_area = 0.0
    for k in range(count):
        following = k + 1 if k + 1 < count else 0
        twice_area += xs[k] * ys[following] - ys[k] * xs[following]
    return twice_area
