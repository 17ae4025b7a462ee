"""The text table of `sianms metrics`: exact lines, the devkit's NaN as '-', classes without GT marked."""

from __future__ import annotations

import math

from sianms_cli.metrics.config import load_config
from sianms_cli.metrics.report import FilterCounts, MetricsReport, RegionMetrics
from sianms_cli.reporting.metrics_table import format_metrics

CONFIG = load_config("paper")
THRESHOLDS = ("0.5", "1.0", "2.0", "4.0")


def _region(**classes: tuple[float, float, int]) -> RegionMetrics:
    """A region from (AP at every threshold, every TP error, GT boxes) per class; 2 predictions each."""
    metrics = ("trans_err", "scale_err", "orient_err", "vel_err", "attr_err")
    tp_errors = {metric: sum(error for _, error, _ in classes.values()) / len(classes) for metric in metrics}
    return RegionMetrics(
        label_aps={name: dict.fromkeys(THRESHOLDS, ap) for name, (ap, _, _) in classes.items()},
        mean_dist_aps={name: ap for name, (ap, _, _) in classes.items()},
        mean_ap=sum(ap for ap, _, _ in classes.values()) / len(classes),
        label_tp_errors={name: dict.fromkeys(metrics, error) for name, (_, error, _) in classes.items()},
        tp_errors=tp_errors, tp_scores={m: max(0.0, 1 - e) for m, e in tp_errors.items()}, nd_score=0.5,
        eval_time=0.01, gt_counts={name: gt for name, (_, _, gt) in classes.items()},
        pred_counts=dict.fromkeys(classes, 2))


def _report(regions: dict[str, RegionMetrics]) -> MetricsReport:
    counts = FilterCounts(loaded=9, kept=9, out_of_range=0, without_points=0, in_bicycle_rack=0)
    return MetricsReport(dataroot="d", version="v1.0-mini", split="mini_val", samples=81, results="r.json",
                         cfg=CONFIG, meta={}, gt_filter=counts, pred_filter=counts, ignored_samples=0,
                         regions=regions, seconds=1.0)


def test_every_class_has_ground_truth():
    region = _region(car=(1.0, 0.0, 3), pedestrian=(0.5, 0.25, 2), bicycle=(0.0, 1.0, 1))
    assert format_metrics(_report({"all": region})).splitlines() == [
        "mini_val: 81 samples, config paper, results r.json",
        "",
        "region all: 6 GT boxes, 6 predictions (after filters)",
        "class                    AP@0.5   AP@1.0   AP@2.0   AP@4.0       AP     ATE     ASE     AOE     AVE     AAE",
        "car                       1.000    1.000    1.000    1.000    1.000   0.000   0.000   0.000   0.000   0.000",
        "pedestrian                0.500    0.500    0.500    0.500    0.500   0.250   0.250   0.250   0.250   0.250",
        "bicycle                   0.000    0.000    0.000    0.000    0.000   1.000   1.000   1.000   1.000   1.000",
        "mean                                                          0.500   0.417   0.417   0.417   0.417   0.417",
        "mAP 0.5000   NDS 0.5000   over 3 classes",
    ]


def test_classes_without_ground_truth_are_marked_and_the_mean_over_the_others_is_given():
    region = _region(car=(1.0, 0.0, 3), pedestrian=(0.0, 1.0, 0), bicycle=(0.0, 1.0, 0))
    region.label_tp_errors["car"]["vel_err"] = math.nan  # the devkit's exemption prints as '-'
    lines = format_metrics(_report({"overlap:CAM_FRONT|CAM_FRONT_RIGHT": region})).splitlines()
    assert lines[2:] == [
        "region overlap:CAM_FRONT|CAM_FRONT_RIGHT: 3 GT boxes, 6 predictions (after filters)",
        "class                    AP@0.5   AP@1.0   AP@2.0   AP@4.0       AP     ATE     ASE     AOE     AVE     AAE",
        "car                       1.000    1.000    1.000    1.000    1.000   0.000   0.000   0.000       -   0.000",
        "pedestrian *              0.000    0.000    0.000    0.000    0.000   1.000   1.000   1.000   1.000   1.000",
        "bicycle *                 0.000    0.000    0.000    0.000    0.000   1.000   1.000   1.000   1.000   1.000",
        "mean                                                          0.333   0.667   0.667   0.667   0.667   0.667",
        "mAP 0.3333   NDS 0.5000   over 3 classes",
        "* 2 classes without ground truth here: AP 0 and TP errors 1 as in the devkit, counted in every mean and NDS",
        "  mAP over the 1 class with ground truth: 1.0000",
    ]


def test_a_region_without_any_ground_truth_says_so_without_a_second_mean():
    region = _region(**dict.fromkeys(CONFIG.class_names, (0.0, 1.0, 0)))
    lines = format_metrics(_report({"non-overlap": region, "all": region})).splitlines()
    note = "* 3 classes without ground truth here: AP 0 and TP errors 1 as in the devkit, counted in every mean and NDS"
    assert lines.count(note) == 2 and "with ground truth:" not in "\n".join(lines)
    assert [line for line in lines if line.startswith("region ")] == [
        "region non-overlap: 0 GT boxes, 6 predictions (after filters)",
        "region all: 0 GT boxes, 6 predictions (after filters)",
    ]
