"""Per-class AP and TP errors, their means and NDS: the devkit's ``DetectionEval.evaluate`` and
``DetectionMetrics`` over filtered box tables.

The summary is a dict with the keys of the devkit's ``metrics_summary.json``: ``label_aps``
{class: {threshold: AP}}, ``mean_dist_aps`` {class: AP}, ``mean_ap``, ``label_tp_errors``
{class: {metric: error}}, ``tp_errors`` {metric: mean over classes}, ``tp_scores``,
``nd_score``, ``eval_time`` (seconds) and ``cfg``. Threshold keys are ``str(float(th))``
("0.5", "1.0", ...) as in the devkit's JSON. NaN marks the devkit's exemptions: orientation,
velocity and attribute errors of traffic cones, velocity and attribute errors of barriers.
"""

from __future__ import annotations

import time
import warnings
from typing import Any

import numpy as np

from sianms_cli.metrics.algo import MetricData, accumulate_thresholds, calc_ap, calc_tp
from sianms_cli.metrics.boxes import DETECTION_NAMES, TP_METRICS
from sianms_cli.metrics.config import DetectionConfig

NAN_TP_METRICS: dict[str, tuple[str, ...]] = {
    "traffic_cone": ("attr_err", "vel_err", "orient_err"),
    "barrier": ("attr_err", "vel_err"),
}
"""TP errors the devkit does not measure for a class (reported as NaN, left out of the means)."""


def threshold_key(dist_th: float) -> str:
    """The JSON key of a threshold in ``label_aps``, as the devkit writes it ("0.5", "2.0")."""
    return str(float(dist_th))


def evaluate_boxes(gt: np.ndarray, pred: np.ndarray, config: DetectionConfig
                   ) -> tuple[dict[str, Any], dict[tuple[str, float], MetricData]]:
    """AP per class and threshold, TP errors per class, means and NDS.

    Args:
        gt, pred: filtered box tables in the devkit's order (see :mod:`.filters`).
        config: the evaluation configuration.

    Returns:
        ``(summary, metric_data)``: the metrics_summary-like dict (module docstring) and the
        101-point curves per (class, threshold).
    """
    started = time.perf_counter()
    metric_data: dict[tuple[str, float], MetricData] = {}
    gt_rows, pred_rows = _rows_by_label(gt), _rows_by_label(pred)
    for class_name, label in zip(config.class_names, config.labels):
        curves = accumulate_thresholds(gt[gt_rows[label]], pred[pred_rows[label]], int(label), config.dist_ths)
        for dist_th, md in zip(config.dist_ths, curves):
            metric_data[(class_name, dist_th)] = md
    label_aps: dict[str, dict[str, float]] = {}
    label_tp_errors: dict[str, dict[str, float]] = {}
    for class_name in config.class_names:
        label_aps[class_name] = {
            threshold_key(th): calc_ap(metric_data[(class_name, th)], config.min_recall, config.min_precision)
            for th in config.dist_ths
        }
        md = metric_data[(class_name, config.dist_th_tp)]
        label_tp_errors[class_name] = {
            metric: (np.nan if metric in NAN_TP_METRICS.get(class_name, ())
                     else calc_tp(md, config.min_recall, metric))
            for metric in TP_METRICS
        }
    summary = summarize(label_aps, label_tp_errors, config)
    summary["eval_time"] = time.perf_counter() - started
    return summary, metric_data


def _rows_by_label(boxes: np.ndarray) -> list[np.ndarray]:
    """Row indices of each label (in table order), from one stable sort."""
    order = np.argsort(boxes["label"], kind="stable")
    bounds = np.searchsorted(boxes["label"][order], np.arange(len(DETECTION_NAMES) + 1))
    return [order[bounds[k]:bounds[k + 1]] for k in range(len(DETECTION_NAMES))]


def summarize(label_aps: dict[str, dict[str, float]], label_tp_errors: dict[str, dict[str, float]],
              config: DetectionConfig) -> dict[str, Any]:
    """The devkit's ``DetectionMetrics.serialize()`` from per-class values (eval_time None)."""
    mean_dist_aps = {name: float(np.mean(list(aps.values()))) for name, aps in label_aps.items()}
    mean_ap = float(np.mean(list(mean_dist_aps.values())))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a metric NaN for every class: NaN
        tp_errors = {
            metric: float(np.nanmean([label_tp_errors[name][metric] for name in config.class_names]))
            for metric in TP_METRICS
        }
    # max(0.0, nan) is 0.0 in Python, as in the devkit: an all-NaN metric scores 0.
    tp_scores = {metric: max(0.0, 1.0 - error) for metric, error in tp_errors.items()}
    nd_score = float(config.mean_ap_weight * mean_ap + np.sum(list(tp_scores.values())))
    nd_score /= float(config.mean_ap_weight + len(tp_scores))
    return {
        "label_aps": label_aps,
        "mean_dist_aps": mean_dist_aps,
        "mean_ap": mean_ap,
        "label_tp_errors": label_tp_errors,
        "tp_errors": tp_errors,
        "tp_scores": tp_scores,
        "nd_score": nd_score,
        "eval_time": None,
        "cfg": config.serialize(),
    }
