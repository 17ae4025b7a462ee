"""3D boxes as aligned arrays: corners and point membership, devkit-compatible.

A box set is ``center (N, 3)``, ``size (N, 3)`` ordered (w, l, h) and ``rotation (N, 4)``
quaternions (w, x, y, z), all in one frame. In the box's own frame x points forward
along the length, y left along the width and z up along the height.
"""

from __future__ import annotations

import numpy as np

from sianms_cli.geometry.quaternion import quat_to_matrix

# Sign of (x, y, z) of each corner relative to the centre, in the devkit's order:
# 0 front-left-top, 1 front-right-top, 2 front-right-bottom, 3 front-left-bottom,
# 4 rear-left-top, 5 rear-right-top, 6 rear-right-bottom, 7 rear-left-bottom.
CORNER_SIGNS = np.array(
    [
        [1, 1, 1],
        [1, -1, 1],
        [1, -1, -1],
        [1, 1, -1],
        [-1, 1, 1],
        [-1, -1, 1],
        [-1, -1, -1],
        [-1, 1, -1],
    ],
    dtype=np.float64,
)

# The 12 edges as corner-index pairs: front face, rear face, then front-to-rear.
BOX_EDGES = np.array(
    [[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4], [0, 4], [1, 5], [2, 6], [3, 7]]
)

# Upper bound on the bytes of the (boxes x points x 3) temporary in points_in_boxes.
_CHUNK_BYTES = 32 * 1024 * 1024


def box_corners(center: np.ndarray, size: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Corners of boxes in the devkit's ``Box.corners()`` order.

    Args:
        center: (N, 3) box centres.
        size: (N, 3) sizes (w, l, h), metres.
        rotation: (N, 4) orientations (w, x, y, z).

    Returns:
        (N, 8, 3) float64 corners in the boxes' frame; index 0 front-left-top,
        1 front-right-top, 2 front-right-bottom, 3 front-left-bottom, 4-7 the same on
        the rear face. N may be 0.
    """
    center, size, rotation = _box_arrays(center, size, rotation)
    if len(center) == 0:
        return np.zeros((0, 8, 3))
    return _corners(center, 0.5 * size[:, [1, 0, 2]], rotation)


def _box_arrays(center: np.ndarray, size: np.ndarray, rotation: np.ndarray) -> tuple[np.ndarray, ...]:
    """(N, 3), (N, 3), (N, 4) float64 views or copies of a box set."""
    return (np.asarray(center, dtype=np.float64).reshape(-1, 3), np.asarray(size, dtype=np.float64).reshape(-1, 3),
            np.asarray(rotation, dtype=np.float64).reshape(-1, 4))


def _corners(center: np.ndarray, half_lwh: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """(N, 8, 3) corners from half (l, w, h); see :func:`box_corners`."""
    local = CORNER_SIGNS[None, :, :] * half_lwh[:, None, :]
    matrices = quat_to_matrix(rotation)
    return np.einsum("nij,nkj->nki", matrices, local) + center[:, None, :]


def points_in_boxes(
    points: np.ndarray, center: np.ndarray, size: np.ndarray, rotation: np.ndarray
) -> np.ndarray:
    """Which points lie in which boxes, with the devkit's ``points_in_box`` semantics.

    Per box, with corners c0..c7 and edge vectors ``i = c4 - c0``, ``j = c1 - c0``,
    ``k = c3 - c0`` and ``v = p - c0``, a point is inside when ``0 <= v.i <= i.i``,
    ``0 <= v.j <= j.j`` and ``0 <= v.k <= k.k`` (bounds inclusive). Boxes are processed
    in chunks so the (boxes x points x 3) temporary stays under 32 MB; peak memory is
    about four times that (about 110 MB for 40k points and 200 boxes).

    Args:
        points: (P, 3) points in the boxes' frame.
        center, size, rotation: (N, 3), (N, 3) (w, l, h), (N, 4) boxes.

    Returns:
        (N, P) bool membership.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    corners = box_corners(center, size, rotation)
    origin = corners[:, 0]
    edges = corners[:, [4, 1, 3]] - origin[:, None, :]
    edge_sq = np.einsum("nej,nej->ne", edges, edges)
    inside = np.zeros((len(corners), len(points)), dtype=bool)
    chunk = max(1, _CHUNK_BYTES // max(1, 24 * len(points)))
    for start in range(0, len(corners), chunk):
        stop = start + chunk
        offsets = points[None, :, :] - origin[start:stop, None, :]
        projections = np.einsum("npj,nej->nep", offsets, edges[start:stop])
        within = (projections >= 0) & (projections <= edge_sq[start:stop, :, None])
        inside[start:stop] = within.all(axis=1)
    return inside


def points_in_own_boxes(
    points: np.ndarray, box: np.ndarray, center: np.ndarray, size: np.ndarray, rotation: np.ndarray
) -> np.ndarray:
    """Whether each point lies in its own box: the test of :func:`points_in_boxes`, one box per point.

    Equal bit for bit to ``points_in_boxes(points[box == n], box n)[0]`` for every n, also
    for points lying on a face, where rounding decides: numpy's einsum rounds differently
    depending on its operands' memory layout, so the corners and edges are kept C-contiguous
    as they are in a one-box call. Points are taken in chunks so the (points x 3 x 3) temporary
    stays under 32 MB.

    Args:
        points: (M, 3) points in the boxes' frame.
        box: (M,) int64 index of each point's box.
        center, size, rotation: (N, 3), (N, 3) (w, l, h), (N, 4) boxes.

    Returns:
        (M,) bool.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    box = np.asarray(box, dtype=np.int64).reshape(-1)
    center, size, rotation = _box_arrays(center, size, rotation)
    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    corners = _corners(center, np.ascontiguousarray(0.5 * size[:, [1, 0, 2]]), rotation)
    origin = corners[:, 0]
    edges = np.ascontiguousarray(corners[:, [4, 1, 3]] - origin[:, None, :])
    edge_sq = np.einsum("nej,nej->ne", edges, edges)
    inside = np.zeros(len(points), dtype=bool)
    chunk = max(1, _CHUNK_BYTES // 72)
    for start in range(0, len(points), chunk):
        mine = box[start:start + chunk]
        offsets = (points[start:start + chunk] - origin[mine])[:, None, :]
        projections = np.einsum("npj,nej->nep", offsets, edges[mine])[:, :, 0]
        inside[start:start + chunk] = ((projections >= 0) & (projections <= edge_sq[mine])).all(axis=1)
    return inside


def count_points_in_boxes(
    points: np.ndarray, center: np.ndarray, size: np.ndarray, rotation: np.ndarray
) -> np.ndarray:
    """Number of points inside each box (see :func:`points_in_boxes`).

    Returns:
        (N,) int64 counts; a point inside two boxes counts for both.
    """
    return points_in_boxes(points, center, size, rotation).sum(axis=1, dtype=np.int64)
