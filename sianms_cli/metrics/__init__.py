"""nuScenes detection metrics on box tables: results files, filters, regions, matching, AP,
TP errors and NDS, with the same numbers as nuscenes-devkit 1.2.0 (see docs/metrics.md).

Knows nothing of models. Boxes travel as one structured array per set (:data:`BOX_DTYPE`).
"""

from sianms_cli.metrics.algo import (
    MetricData,
    accumulate,
    accumulate_thresholds,
    attr_acc,
    calc_ap,
    calc_tp,
    center_distance,
    cummean,
    scale_iou,
    velocity_l2,
    yaw_diff,
)
from sianms_cli.metrics.boxes import (
    ATTRIBUTE_NAMES,
    BOX_DTYPE,
    DETECTION_NAMES,
    TP_METRICS,
    empty_boxes,
    make_boxes,
)
from sianms_cli.metrics.config import PRESETS, DetectionConfig, load_config
from sianms_cli.metrics.dataset import EvalSplit, eval_split, ground_truth
from sianms_cli.metrics.evaluate import MetricsConfig, align_results, evaluate
from sianms_cli.metrics.metrics import evaluate_boxes
from sianms_cli.metrics.report import (
    FilterCounts,
    MetricsReport,
    RegionMetrics,
    read_report,
    report_json,
    write_report,
)
from sianms_cli.metrics.results import (
    Results,
    ResultsFormatError,
    read_results,
    results_from_boxes,
    validate_results,
    write_results,
)

__all__ = [
    "ATTRIBUTE_NAMES",
    "BOX_DTYPE",
    "DETECTION_NAMES",
    "PRESETS",
    "TP_METRICS",
    "DetectionConfig",
    "EvalSplit",
    "FilterCounts",
    "MetricData",
    "MetricsConfig",
    "MetricsReport",
    "RegionMetrics",
    "Results",
    "ResultsFormatError",
    "accumulate",
    "accumulate_thresholds",
    "align_results",
    "attr_acc",
    "calc_ap",
    "calc_tp",
    "center_distance",
    "cummean",
    "empty_boxes",
    "eval_split",
    "evaluate",
    "evaluate_boxes",
    "ground_truth",
    "load_config",
    "make_boxes",
    "read_report",
    "read_results",
    "report_json",
    "results_from_boxes",
    "scale_iou",
    "validate_results",
    "velocity_l2",
    "write_report",
    "write_results",
    "yaw_diff",
]
