"""Association of 2D detections with projected ground-truth boxes by 2D IoU.

The paper associates labels with the predicted boxes by their IoU in the image plane
(paper §IV-B); we solve it as an optimal assignment (maximum total IoU,
``scipy.optimize.linear_sum_assignment``) so a ground-truth box is never claimed twice and
the result does not depend on the order of the detections.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from sianms_cli.errors import SianmsError


def box_iou(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """IoU of every pair of 2D boxes (no +1 pixel convention, as torchvision).

    Args:
        boxes_a: (N, 4) [x1, y1, x2, y2].
        boxes_b: (M, 4) [x1, y1, x2, y2].

    Returns:
        (N, M) float64; 0 where the union is empty.
    """
    a = np.asarray(boxes_a, dtype=np.float64).reshape(-1, 4)
    b = np.asarray(boxes_b, dtype=np.float64).reshape(-1, 4)
    area_a = np.clip(a[:, 2] - a[:, 0], 0, None) * np.clip(a[:, 3] - a[:, 1], 0, None)
    area_b = np.clip(b[:, 2] - b[:, 0], 0, None) * np.clip(b[:, 3] - b[:, 1], 0, None)
    width = np.clip(np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0]), 0, None)
    height = np.clip(np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1]), 0, None)
    inter = width * height
    union = area_a[:, None] + area_b[None, :] - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def associate(
    det_boxes: np.ndarray,
    gt_boxes: np.ndarray,
    iou_threshold: float = 0.5,
    det_classes: np.ndarray | None = None,
    gt_classes: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Match detections to ground-truth boxes one-to-one, maximising the total IoU.

    A pair may match only if its IoU is ``>= iou_threshold`` and, when both class arrays
    are given, the classes are equal. Among the admissible pairs the assignment maximises
    the summed IoU (ties broken by scipy's solver, deterministically).

    Args:
        det_boxes: (N, 4) detections [x1, y1, x2, y2].
        gt_boxes: (M, 4) ground-truth boxes.
        iou_threshold: minimum IoU of a match, in (0, 1].
        det_classes, gt_classes: optional (N,), (M,) class names.

    Returns:
        ``(gt_index, iou)``: (N,) int64 matched ground-truth row or -1, and (N,) float64
        IoU with it (0 when unmatched).
    """
    if not 0 < iou_threshold <= 1:
        raise SianmsError(f"association IoU threshold must be in (0, 1], got {iou_threshold}")
    iou = box_iou(det_boxes, gt_boxes)
    count = iou.shape[0]
    gt_index = np.full(count, -1, dtype=np.int64)
    matched_iou = np.zeros(count)
    if iou.size == 0:
        return gt_index, matched_iou
    admissible = iou >= iou_threshold
    if det_classes is not None and gt_classes is not None:
        admissible &= np.asarray(det_classes, dtype=str)[:, None] == np.asarray(gt_classes, dtype=str)[None, :]
    # Inadmissible pairs get a cost above every admissible one (DeepSORT's pattern): the
    # solver always succeeds and such pairs are dropped after solving.
    cost = np.where(admissible, 1.0 - iou, 2.0)
    rows, cols = linear_sum_assignment(cost)
    keep = admissible[rows, cols]
    gt_index[rows[keep]] = cols[keep]
    matched_iou[rows[keep]] = iou[rows[keep], cols[keep]]
    return gt_index, matched_iou
