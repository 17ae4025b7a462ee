"""siaNMS re-identification between contiguous cameras (paper §III-B), and its ground-truth oracle.

For each contiguous camera pair (a, b) of a sample (docs/methods.md#matching-contiguous-cameras):

1. **Candidates** are the detections of each camera that lie on the part of its image the
   other camera also sees (:func:`overlap_columns`: the image columns whose viewing rays,
   at infinity, fall inside the other camera's image). The rule uses the calibration only,
   never the ground truth.
2. Their embeddings' L2 distances form a cost matrix; a pair is **forbidden** when the
   distance is above ``dis_thr``, when the classes differ, or when a class is not matched
   (siaNMS handles cars only by default, as the paper).
3. **Optimal assignment** (Hungarian, :func:`assign`) of the allowed pairs: as many allowed
   matches as possible, and among those the smallest total distance; forbidden pairs never
   match.

The oracle (:func:`oracle_matches`) pairs the same candidates by their ground-truth instance,
so it shows the ceiling of re-identification under the same candidate rule.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from sianms_cli.geometry.frustum import pixel_rays


def overlap_columns(intrinsic_a: np.ndarray, size_a: tuple[int, int], rotation_a_to_b: np.ndarray,
                    intrinsic_b: np.ndarray, size_b: tuple[int, int]) -> tuple[float, float] | None:
    """The span [u_min, u_max] of camera a's image columns whose rays at infinity camera b sees.

    Rays are taken through the image's middle row; at infinity the cameras' baseline does not
    matter, so only the rotation between them counts. Near objects see a slightly narrower
    overlap, so the band is a superset of where a duplicate can appear.

    Args:
        intrinsic_a, intrinsic_b: (3, 3) camera matrices.
        size_a, size_b: image sizes (W, H), pixels.
        rotation_a_to_b: (3, 3) rotation of camera a's frame into camera b's.

    Returns:
        (u_min, u_max) in pixels of camera a, or None when no column of a is seen by b.
    """
    width_a, height_a = size_a
    width_b, height_b = size_b
    columns = np.arange(width_a, dtype=np.float64) + 0.5
    rays = pixel_rays(np.stack([columns, np.full(width_a, height_a / 2)], axis=1), intrinsic_a)
    in_b = rays @ np.asarray(rotation_a_to_b, dtype=np.float64).T
    projected = in_b @ np.asarray(intrinsic_b, dtype=np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        u = projected[:, 0] / projected[:, 2]
    seen = (in_b[:, 2] > 0) & (u >= 0) & (u <= width_b)
    if not seen.any():
        return None
    return float(columns[seen].min() - 0.5), float(columns[seen].max() + 0.5)


def in_columns(boxes2d: np.ndarray, span: tuple[float, float] | None) -> np.ndarray:
    """(N,) bool: the 2-D boxes whose horizontal extent meets the column span."""
    boxes2d = np.asarray(boxes2d, dtype=np.float64).reshape(-1, 4)
    if span is None:
        return np.zeros(len(boxes2d), dtype=bool)
    return (boxes2d[:, 2] >= span[0]) & (boxes2d[:, 0] <= span[1])


def pair_distances(embedding_a: np.ndarray, embedding_b: np.ndarray) -> np.ndarray:
    """(A, B) L2 distances between two sets of embeddings, in float64."""
    a = np.asarray(embedding_a, dtype=np.float64)
    b = np.asarray(embedding_b, dtype=np.float64)
    squared = (a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2.0 * a @ b.T
    return np.sqrt(np.maximum(squared, 0.0))


def allowed_pairs(distance: np.ndarray, classes_a: np.ndarray, classes_b: np.ndarray, threshold: float,
                  matched_classes: tuple[str, ...]) -> np.ndarray:
    """(A, B) bool: pairs within ``threshold`` of the same class, a class siaNMS matches."""
    classes_a, classes_b = np.asarray(classes_a, dtype=str), np.asarray(classes_b, dtype=str)
    same = classes_a[:, None] == classes_b[None, :]
    matched = np.isin(classes_a, matched_classes)[:, None]
    return (np.asarray(distance) <= threshold) & same & matched


def assign(cost: np.ndarray, allowed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Optimal one-to-one assignment of the allowed pairs of a cost matrix.

    Forbidden pairs cost more than any set of allowed ones, so the Hungarian method first
    maximises the number of allowed matches, then minimises their total cost; the forbidden
    pairs it must still fill the square with are dropped.

    Args:
        cost: (A, B) finite costs (distances).
        allowed: (A, B) bool.

    Returns:
        (rows, cols): the matched pairs, sorted by row.
    """
    cost = np.asarray(cost, dtype=np.float64)
    allowed = np.asarray(allowed, dtype=bool)
    if not allowed.any():
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    spread = float(np.abs(cost[allowed]).max()) + 1.0
    penalty = spread * (min(cost.shape) + 1)  # above the total of any allowed assignment
    rows, cols = linear_sum_assignment(np.where(allowed, cost, penalty))
    keep = allowed[rows, cols]
    return rows[keep].astype(np.int64), cols[keep].astype(np.int64)


def oracle_matches(instances_a: np.ndarray, instances_b: np.ndarray, classes_a: np.ndarray, classes_b: np.ndarray,
                   matched_classes: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The pairs of candidates that are the same ground-truth instance ("" = none), sorted by row."""
    instances_a, instances_b = np.asarray(instances_a, dtype=str), np.asarray(instances_b, dtype=str)
    same = (instances_a[:, None] == instances_b[None, :]) & (instances_a[:, None] != "")
    allowed = same & allowed_pairs(np.zeros(same.shape), classes_a, classes_b, 0.0, matched_classes)
    return assign(np.zeros(same.shape), allowed)


def pair_quality(matched: int, correct: int, true_pairs: int) -> dict[str, float | None]:
    """Re-identification precision, recall and F1 against ground-truth identity (None when undefined)."""
    precision = correct / matched if matched else None
    recall = correct / true_pairs if true_pairs else None
    f1 = 2 * correct / (matched + true_pairs) if matched + true_pairs else None
    return {"pairs_matched": matched, "pairs_correct": correct, "pairs_true": true_pairs,
            "precision": precision, "recall": recall, "f1": f1}
