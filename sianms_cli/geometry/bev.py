"""Bird's-eye-view (BEV) geometry of boxes, vectorised over boxes and box pairs.

A BEV box is ``(x, y, width, length, yaw)`` in the nuScenes global frame (z up): centre in
metres, width and length in metres, yaw in radians, the angle of the length axis from +x,
counter-clockwise. Box sets travel as ``centers (N, 2)``, ``sizes (N, 2)`` ordered
(width, length) and ``yaw (N,)``, or stacked as ``boxes (N, 5)`` in the column order above.

IoU is ``intersection / max(union, 1e-8)`` as in OpenPCDet's ``iou_normal`` / ``boxes_iou_bev``,
so boxes of zero area give 0, never NaN. Rotated intersections are
Sutherland–Hodgman clipping of one rectangle by the four inner half-planes of the other plus
the shoelace formula, for all pairs at once (no Python loop per box or pair).

"Axis-aligned" BEV boxes have three meanings in the toolkits (docs/methods.md#axis-aligned-nms), named by
:data:`AXIS_MODES`:

- ``ignore-yaw``: centre ± (length/2, width/2), as the box would be at yaw 0 (MM3D
  ``nms_normal_bev``, PCDet ``nms_normal_gpu``);
- ``nearest-bev``: the same, with the extents swapped when |yaw wrapped to [-pi/2, pi/2)|
  > pi/4, so the box is the axis-aligned one nearest in orientation (MM3D ``nearest_bev``);
- ``enclosing``: the smallest axis-aligned rectangle holding the rotated corners ("standup").
"""

from __future__ import annotations

import numpy as np

from sianms_cli.errors import SianmsError

AXIS_MODES = ("ignore-yaw", "nearest-bev", "enclosing")

# The IoU denominator floor of PCDet (``max(union, 1e-8)``): degenerate pairs give 0, not NaN.
UNION_FLOOR = 1e-8

# Corner signs along (length, width), counter-clockwise seen from above (+z).
_CORNER_SIGNS = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])

# A convex quadrilateral clipped by four half-planes keeps at most 4 + 4 vertices.
_MAX_VERTICES = 8


def split_boxes(boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(centers (N, 2), sizes (N, 2), yaw (N,))`` of ``boxes (N, 5)`` (x, y, width, length, yaw)."""
    boxes = np.asarray(boxes, dtype=np.float64)
    if boxes.ndim != 2 or boxes.shape[1] != 5:
        raise SianmsError(f"BEV boxes must be an (N, 5) array (x, y, width, length, yaw), got shape {boxes.shape}")
    return boxes[:, :2], boxes[:, 2:4], boxes[:, 4]


def check_boxes(centers: np.ndarray, sizes: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The three arrays as float64 ``(N, 2), (N, 2), (N,)``; SianmsError on a shape mismatch,
    a non-finite value or a negative size."""
    centers = np.asarray(centers, dtype=np.float64)
    sizes = np.asarray(sizes, dtype=np.float64)
    yaw = np.asarray(yaw, dtype=np.float64)
    count = len(centers) if centers.ndim == 2 else -1
    if centers.shape != (count, 2) or sizes.shape != (count, 2) or yaw.shape != (count,):
        raise SianmsError(f"BEV boxes need centers (N, 2), sizes (N, 2) and yaw (N,), got shapes "
                          f"{centers.shape}, {sizes.shape} and {yaw.shape}")
    if not (np.isfinite(centers).all() and np.isfinite(sizes).all() and np.isfinite(yaw).all()):
        raise SianmsError("BEV boxes must be finite (a centre, size or yaw is NaN or infinite)")
    if (sizes < 0).any():
        raise SianmsError(f"BEV box sizes must be >= 0, got {sizes.min()}")
    return centers, sizes, yaw


def bev_corners(centers: np.ndarray, sizes: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(N, 4, 2) corners (x, y) in metres, counter-clockwise seen from above.

    Args:
        centers: (N, 2) box centres (x, y), metres.
        sizes: (N, 2) (width, length), metres.
        yaw: (N,) angle of the length axis from +x, counter-clockwise, radians.

    The first corner is front-left (+length/2, +width/2 in the box frame).
    """
    centers, sizes, yaw = check_boxes(centers, sizes, yaw)
    cos, sin = np.cos(yaw), np.sin(yaw)
    half_length = 0.5 * sizes[:, 1, None] * _CORNER_SIGNS[:, 0]  # (N, 4)
    half_width = 0.5 * sizes[:, 0, None] * _CORNER_SIGNS[:, 1]
    x = centers[:, 0, None] + half_length * cos[:, None] - half_width * sin[:, None]
    y = centers[:, 1, None] + half_length * sin[:, None] + half_width * cos[:, None]
    return np.stack([x, y], axis=2)


def quad_areas(corners: np.ndarray) -> np.ndarray:
    """(N,) areas of counter-clockwise parallelograms given by ``corners (N, 4, 2)``.

    The cross product of two adjacent edges: computed from the same corners as the
    intersection, so a box and its own intersection with itself agree to rounding.
    """
    first = corners[:, 1] - corners[:, 0]
    second = corners[:, 2] - corners[:, 1]
    return first[:, 0] * second[:, 1] - first[:, 1] * second[:, 0]


def rotated_intersection_areas(corners_a: np.ndarray, corners_b: np.ndarray) -> np.ndarray:
    """(E,) area of quadrilateral a[e] ∩ quadrilateral b[e], in square metres.

    Args:
        corners_a, corners_b: (E, 4, 2) counter-clockwise corners of convex quadrilaterals
            (as :func:`bev_corners` gives them); pairs are row e with row e.

    A pair with a zero-area quadrilateral gives 0: clipping by a zero-length edge would keep
    everything, so such pairs are not clipped at all.
    """
    areas = np.zeros(len(corners_a))
    solid = np.flatnonzero((quad_areas(corners_a) > 0) & (quad_areas(corners_b) > 0))
    polygons = np.zeros((len(solid), _MAX_VERTICES, 2))
    polygons[:, :4] = corners_a[solid]
    counts = np.full(len(solid), 4)
    clip = corners_b[solid]
    for edge in range(4):
        polygons, counts = _clip_by_edge(polygons, counts, clip[:, edge], clip[:, (edge + 1) % 4])
    areas[solid] = np.maximum(_shoelace(polygons, counts), 0.0)
    return areas


def _clip_by_edge(polygons: np.ndarray, counts: np.ndarray, start: np.ndarray,
                  end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One Sutherland–Hodgman pass: the part of each polygon left of (or on) start -> end.

    Every live vertex emits itself when inside and the crossing point when its edge to the
    next vertex changes sides; the emitted points are compacted, in order, to the front.
    Polygons that lie wholly inside are returned untouched, which is most of them.

    Args:
        polygons: (E, 8, 2) vertices; the first ``counts[e]`` of row e are its polygon.
        counts: (E,) vertex counts.
        start, end: (E, 2) the clipping edge of each row.
    """
    direction = end - start
    side = (direction[:, None, 0] * (polygons[..., 1] - start[:, None, 1])
            - direction[:, None, 1] * (polygons[..., 0] - start[:, None, 0]))
    slot = np.arange(_MAX_VERTICES)
    alive = slot < counts[:, None]
    inside = side >= 0
    cut = np.flatnonzero((alive & ~inside).any(axis=1))
    if len(cut) == 0:
        return polygons, counts
    part, part_side, part_alive, part_inside = polygons[cut], side[cut], alive[cut], inside[cut]
    following_index = np.where(slot + 1 < counts[cut, None], slot + 1, 0)
    following = np.take_along_axis(part, following_index[..., None], axis=1)
    side_following = np.take_along_axis(part_side, following_index, axis=1)
    kept = part_alive & part_inside
    crossing = part_alive & (part_inside != (side_following >= 0))
    # The two sides have opposite signs where crossing, so the denominator is never 0.
    t = np.divide(part_side, part_side - side_following, out=np.zeros_like(part_side), where=crossing)
    crossings = part + t[..., None] * (following - part)
    emitted = np.stack([part, crossings], axis=2).reshape(len(cut), 2 * _MAX_VERTICES, 2)
    valid = np.stack([kept, crossing], axis=2).reshape(len(cut), 2 * _MAX_VERTICES)
    # Stable sort puts the valid points first, in their order; a convex result never needs
    # more than 8 slots, so the tail (invalid points) is dropped.
    order = np.argsort(~valid, axis=1, kind="stable")[:, :_MAX_VERTICES]
    polygons = polygons.copy()
    counts = counts.copy()
    polygons[cut] = np.take_along_axis(emitted, order[..., None], axis=1)
    counts[cut] = np.minimum(valid.sum(axis=1), _MAX_VERTICES)
    return polygons, counts


def _shoelace(polygons: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """(E,) signed areas of polygons (E, 8, 2) with ``counts`` vertices (0 below 3).

    Coordinates are taken relative to the first vertex, so large global coordinates
    (nuScenes maps span kilometres) do not cost precision.
    """
    slot = np.arange(_MAX_VERTICES)
    following_index = np.where(slot + 1 < counts[:, None], slot + 1, 0)
    local = polygons - polygons[:, :1]
    following = np.take_along_axis(local, following_index[..., None], axis=1)
    cross = local[..., 0] * following[..., 1] - local[..., 1] * following[..., 0]
    return 0.5 * np.where(slot < counts[:, None], cross, 0.0).sum(axis=1)


def rotated_iou_from_corners(corners_a: np.ndarray, corners_b: np.ndarray) -> np.ndarray:
    """(E,) rotated BEV IoU of quadrilateral pairs ``corners_a[e]``, ``corners_b[e]`` (E, 4, 2)."""
    intersection = rotated_intersection_areas(corners_a, corners_b)
    union = quad_areas(corners_a) + quad_areas(corners_b) - intersection
    return intersection / np.maximum(union, UNION_FLOOR)


def rotated_iou_pairs(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """(N,) exact rotated BEV IoU of box ``boxes_a[i]`` with box ``boxes_b[i]``.

    Args:
        boxes_a, boxes_b: (N, 5) boxes (x, y, width, length, yaw), see the module docstring.
    """
    corners_a, corners_b = bev_corners(*split_boxes(boxes_a)), bev_corners(*split_boxes(boxes_b))
    if len(corners_a) != len(corners_b):
        raise SianmsError(f"rotated_iou_pairs needs as many boxes in a as in b, "
                          f"got {len(corners_a)} and {len(corners_b)}")
    return rotated_iou_from_corners(corners_a, corners_b)


def rotated_iou_matrix(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """(N, M) exact rotated BEV IoU of every box of ``boxes_a (N, 5)`` with every box of ``boxes_b (M, 5)``.

    Clips all N x M pairs at once (about 1 kB of temporaries per pair): meant for small sets
    and tests; NMS over many boxes clips only candidate pairs (:mod:`sianms_cli.evaluation.nms`).
    """
    corners_a, corners_b = bev_corners(*split_boxes(boxes_a)), bev_corners(*split_boxes(boxes_b))
    rows, columns = np.divmod(np.arange(len(corners_a) * len(corners_b)), len(corners_b))
    iou = rotated_iou_from_corners(corners_a[rows], corners_b[columns])
    return iou.reshape(len(corners_a), len(corners_b))


def check_axis_mode(mode: str) -> str:
    """``mode`` if it is one of :data:`AXIS_MODES`, else SianmsError naming the choices."""
    if mode not in AXIS_MODES:
        raise SianmsError(f"unknown axis-aligned BEV mode {mode!r}; choose one of {', '.join(AXIS_MODES)}")
    return mode


def axis_aligned_rectangles(centers: np.ndarray, sizes: np.ndarray, yaw: np.ndarray, mode: str) -> np.ndarray:
    """(N, 4) axis-aligned BEV rectangles (x_min, y_min, x_max, y_max), metres, in one of :data:`AXIS_MODES`.

    Args:
        centers: (N, 2) box centres, metres.
        sizes: (N, 2) (width, length), metres.
        yaw: (N,) radians, the angle of the length axis from +x.
        mode: ``ignore-yaw``, ``nearest-bev`` or ``enclosing`` (module docstring).
    """
    check_axis_mode(mode)
    centers, sizes, yaw = check_boxes(centers, sizes, yaw)
    if mode == "enclosing":  # the extents of the rotated corners, without building them
        cos, sin = np.abs(np.cos(yaw)), np.abs(np.sin(yaw))
        half = 0.5 * np.column_stack([sizes[:, 1] * cos + sizes[:, 0] * sin, sizes[:, 1] * sin + sizes[:, 0] * cos])
        return np.concatenate([centers - half, centers + half], axis=1)
    # At yaw 0 the length runs along x: half-extents (length/2, width/2).
    half = 0.5 * sizes[:, ::-1]
    if mode == "nearest-bev":
        wrapped = yaw - np.floor(yaw / np.pi + 0.5) * np.pi  # MM3D limit_period(yaw, 0.5, pi): [-pi/2, pi/2)
        half = np.where((np.abs(wrapped) > np.pi / 4)[:, None], half[:, ::-1], half)
    return np.concatenate([centers - half, centers + half], axis=1)


def rectangle_iou(rectangles_a: np.ndarray, rectangles_b: np.ndarray) -> np.ndarray:
    """IoU of axis-aligned rectangles (..., 4) (x_min, y_min, x_max, y_max); broadcasts like numpy.

    Pairs: two (N, 4) arrays give (N,); a matrix: ``a[:, None]`` and ``b[None]`` give (N, M).
    """
    low = np.maximum(rectangles_a[..., :2], rectangles_b[..., :2])
    high = np.minimum(rectangles_a[..., 2:], rectangles_b[..., 2:])
    intersection = np.prod(np.maximum(high - low, 0.0), axis=-1)
    area_a = np.prod(rectangles_a[..., 2:] - rectangles_a[..., :2], axis=-1)
    area_b = np.prod(rectangles_b[..., 2:] - rectangles_b[..., :2], axis=-1)
    return intersection / np.maximum(area_a + area_b - intersection, UNION_FLOOR)


def axis_iou_pairs(boxes_a: np.ndarray, boxes_b: np.ndarray, mode: str = "ignore-yaw") -> np.ndarray:
    """(N,) axis-aligned BEV IoU of box ``boxes_a[i]`` with ``boxes_b[i]`` (both (N, 5)) in ``mode``."""
    rectangles_a = axis_aligned_rectangles(*split_boxes(boxes_a), mode)
    rectangles_b = axis_aligned_rectangles(*split_boxes(boxes_b), mode)
    if len(rectangles_a) != len(rectangles_b):
        raise SianmsError(f"axis_iou_pairs needs as many boxes in a as in b, "
                          f"got {len(rectangles_a)} and {len(rectangles_b)}")
    return rectangle_iou(rectangles_a, rectangles_b)


def axis_iou_matrix(boxes_a: np.ndarray, boxes_b: np.ndarray, mode: str = "ignore-yaw") -> np.ndarray:
    """(N, M) axis-aligned BEV IoU of every box of ``boxes_a (N, 5)`` with every box of ``boxes_b (M, 5)``."""
    rectangles_a = axis_aligned_rectangles(*split_boxes(boxes_a), mode)
    rectangles_b = axis_aligned_rectangles(*split_boxes(boxes_b), mode)
    return rectangle_iou(rectangles_a[:, None], rectangles_b[None])
