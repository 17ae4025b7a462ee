"""What `sianms eval` measures besides the nuScenes metrics: duplicates left, and the curves kept.

A **duplicate** is a prediction that is a false positive at the matching threshold of the TP
errors (2 m) although a ground-truth box of its class lies within that distance in its
sample: the box was there, another prediction took it first. That is what a duplicate
suppressor exists to remove; counted per class and region with the devkit's own greedy
matching (:func:`sianms_cli.metrics.algo.greedy_match`).
"""

from __future__ import annotations

import numpy as np

from sianms_cli.metrics.algo import MetricData, greedy_match, processing_order
from sianms_cli.metrics.boxes import LABEL
from sianms_cli.metrics.evaluate import details_of


def near_ground_truth(gt_sample: np.ndarray, gt_xy: np.ndarray, pred_sample: np.ndarray, pred_xy: np.ndarray,
                      radius: float) -> np.ndarray:
    """(P,) bool: a ground-truth centre of the same sample lies within ``radius`` (strict <) of each prediction."""
    order = np.argsort(gt_sample, kind="stable")
    gt_sample, gt_xy = gt_sample[order], gt_xy[order]
    first = np.searchsorted(gt_sample, pred_sample, side="left")
    count = np.searchsorted(gt_sample, pred_sample, side="right") - first
    pred_of_pair = np.repeat(np.arange(len(pred_sample)), count)
    gt_of_pair = np.repeat(first - np.concatenate([[0], np.cumsum(count)[:-1]]), count) + np.arange(count.sum())
    close = np.hypot(*(gt_xy[gt_of_pair] - pred_xy[pred_of_pair]).T) < radius
    near = np.zeros(len(pred_sample), dtype=bool)
    near[pred_of_pair[close]] = True
    return near


def duplicates(gt: np.ndarray, pred: np.ndarray, class_name: str, distance: float) -> int:
    """Predictions of ``class_name`` that are duplicates (module docstring) in these box tables."""
    label = LABEL[class_name]
    gt, pred = gt[gt["label"] == label], pred[pred["label"] == label]
    if len(pred) == 0 or len(gt) == 0:
        return 0
    matched, _ = greedy_match(gt["sample"], gt["translation"][:, :2], pred["sample"], pred["translation"][:, :2],
                              processing_order(pred["score"]), [distance])
    false_positive = matched[0] < 0
    near = near_ground_truth(gt["sample"], gt["translation"][:, :2], pred["sample"][false_positive],
                             pred["translation"][false_positive, :2], distance)
    return int(near.sum())


class RegionFigures:
    """Collects, per region, the duplicates per class and, for the regions in ``curve_regions``,
    the devkit's 101-point curves of every class and threshold (``metrics_details.json``).

    Pass :meth:`collect` as ``inspect`` to :func:`sianms_cli.metrics.evaluate.evaluate`.
    """

    def __init__(self, classes: tuple[str, ...], distance: float, curve_regions: tuple[str, ...]) -> None:
        self.classes, self.distance, self.curve_regions = classes, distance, curve_regions
        self.duplicates: dict[str, dict[str, int]] = {}
        self.curves: dict[str, dict[str, MetricData]] = {}

    def collect(self, region: str, gt: np.ndarray, pred: np.ndarray, curves: dict) -> None:
        self.duplicates[region] = {name: duplicates(gt, pred, name, self.distance) for name in self.classes}
        if region in self.curve_regions:
            self.curves[region] = details_of(curves)
