"""The text table of `sianms metrics`: one block per region, as the devkit prints its summary.

Per class: AP at each distance threshold, their mean, and the five TP errors (NaN, the
devkit's exemptions, prints as ``-``); then the means, mAP and NDS. A class without
ground truth in the region is marked ``*``: the devkit scores it AP 0 and TP errors 1 and
keeps it in every mean, which a reader of a camera-pair region would not expect, so the
block says so and adds the mean AP over the classes that do have ground truth there.
"""

from __future__ import annotations

import math

from sianms_cli.metrics.boxes import TP_METRICS
from sianms_cli.metrics.metrics import threshold_key
from sianms_cli.metrics.report import MetricsReport, RegionMetrics

TP_HEADERS = {"trans_err": "ATE", "scale_err": "ASE", "orient_err": "AOE", "vel_err": "AVE", "attr_err": "AAE"}
NO_GT_MARK = "*"
_CLASS_WIDTH, _AP_WIDTH, _TP_WIDTH = 22, 9, 8


def format_metrics(report: MetricsReport) -> str:
    """The report as text: a title line, then one block per region (:func:`format_region`)."""
    lines = [f"{report.split}: {report.samples} samples, config {report.cfg.name}, results {report.results}"]
    for name, region in report.regions.items():
        lines += ["", *format_region(name, region, report.cfg.dist_ths)]
    return "\n".join(lines)


def format_region(name: str, region: RegionMetrics, dist_ths: tuple[float, ...]) -> list[str]:
    """The lines of one region: box counts, the class table, mAP and NDS, the no-GT note."""
    thresholds = [threshold_key(th) for th in dist_ths]
    without_gt = region.classes_without_gt
    lines = [
        f"region {name}: {sum(region.gt_counts.values())} GT boxes, "
        f"{sum(region.pred_counts.values())} predictions (after filters)",
        f"{'class':<{_CLASS_WIDTH}}" + "".join(f"{'AP@' + t:>{_AP_WIDTH}}" for t in thresholds)
        + f"{'AP':>{_AP_WIDTH}}" + "".join(f"{TP_HEADERS[m]:>{_TP_WIDTH}}" for m in TP_METRICS),
    ]
    for cls in region.classes:
        label = f"{cls} {NO_GT_MARK}" if cls in without_gt else cls
        lines.append(f"{label:<{_CLASS_WIDTH}}"
                     + "".join(_cell(region.label_aps[cls][t], _AP_WIDTH) for t in thresholds)
                     + _cell(region.mean_dist_aps[cls], _AP_WIDTH)
                     + "".join(_cell(region.label_tp_errors[cls][m], _TP_WIDTH) for m in TP_METRICS))
    lines.append(f"{'mean':<{_CLASS_WIDTH}}" + " " * (_AP_WIDTH * len(thresholds)) + _cell(region.mean_ap, _AP_WIDTH)
                 + "".join(_cell(region.tp_errors[m], _TP_WIDTH) for m in TP_METRICS))
    lines.append(f"mAP {region.mean_ap:.4f}   NDS {region.nd_score:.4f}   over {_classes(len(region.classes))}")
    return lines + _no_gt_note(region)


def _no_gt_note(region: RegionMetrics) -> list[str]:
    """What the devkit's rule did to this region's means, when a class had no ground truth."""
    without_gt = len(region.classes_without_gt)
    if without_gt == 0:
        return []
    note = (f"{NO_GT_MARK} {_classes(without_gt)} without ground truth here: AP 0 and TP errors 1 as in the devkit, "
            "counted in every mean and NDS")
    with_gt = len(region.classes) - without_gt
    if with_gt == 0:
        return [note]
    return [note, f"  mAP over the {_classes(with_gt)} with ground truth: {region.mean_ap_of_classes_with_gt:.4f}"]


def _classes(count: int) -> str:
    return f"{count} class" if count == 1 else f"{count} classes"


def _cell(value: float, width: int) -> str:
    if math.isnan(value):
        return f"{'-':>{width}}"
    return f"{value:>{width}.3f}"
