"""`sianms eval`'s comparison as Table I of the paper: regions × methods × (AP, ATE, ASE, AOE).

Units follow the paper's table: AP and ASE in percent, ATE in metres, AOE in radians; the
paper's own numbers (nuScenes validation set, car) are printed beside for orientation,
not as a target: they come from another detector on real data. A class without ground
truth in a region has no figure there (the devkit would score it AP 0).

For every NMS family the table names the threshold with the best car AP over the whole
split, so a baseline is read at its best as well as at the paper's 0.3.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

from sianms_cli.metrics.report import MetricsReport
from sianms_cli.evaluation.methods import IOU_METHODS, split_name

TABLE_CLASS = "car"  # Table I is car only (paper §V-B: siaNMS matches cars)
REGIONS_SHOWN = (("all", "All"), ("overlap", "Overlap"))
PAPER_TABLE_I = {  # paper §V, Table I: F-PointNets on nuScenes val, car
    "All": {"vanilla": (45.5, 0.331, 18.4, 0.371), "axis-nms": (49.1, 0.330, 18.4, 0.367),
            "sianms": (51.1, 0.320, 18.2, 0.350)},
    "Overlap": {"vanilla": (37.9, 0.317, 18.6, 0.312), "axis-nms": (46.6, 0.312, 18.6, 0.306),
                "sianms": (49.0, 0.287, 18.0, 0.253)},
}
COLUMNS = ("AP", "ATE", "ASE", "AOE")
REID_WRONG_COLUMNS = ("wrong, no true partner", "wrong, partner passed over", "dismissed (frustums apart)",
                      "dismissed but right", "refused by the gate", "refused but right")
REID_WRONG_FIGURES = ("wrong_without_partner", "wrong_partner_passed_over", "dismissed", "dismissed_right",
                      "gate_refused", "gate_refused_right")


def class_figures(report: MetricsReport, region: str, name: str) -> dict[str, float | int | None]:
    """AP (%), ATE (m), ASE (%), AOE (rad) of a class in a region, and its box counts; None without GT."""
    metrics = report.regions[region]
    gt, pred = int(metrics.gt_counts.get(name, 0)), int(metrics.pred_counts.get(name, 0))
    if gt == 0:
        return {"AP": None, "ATE": None, "ASE": None, "AOE": None, "gt": gt, "pred": pred}
    errors = metrics.label_tp_errors[name]
    return {"AP": 100.0 * metrics.mean_dist_aps[name], "ATE": _finite(errors["trans_err"]),
            "ASE": _finite(100.0 * errors["scale_err"]), "AOE": _finite(errors["orient_err"]), "gt": gt, "pred": pred}


def _finite(value: float) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def best_thresholds(reports: Mapping[str, MetricsReport]) -> dict[str, str]:
    """For each IoU-NMS family evaluated, the variant with the best car AP over the split."""
    best: dict[str, tuple[float, str]] = {}
    for method, report in reports.items():
        family, _ = split_name(method)
        if family not in IOU_METHODS or TABLE_CLASS not in report.regions["all"].mean_dist_aps:
            continue
        ap = report.regions["all"].mean_dist_aps[TABLE_CLASS]
        if family not in best or ap > best[family][0]:
            best[family] = (ap, method)
    return {family: method for family, (_, method) in best.items()}


def eval_table(reports: Mapping[str, MetricsReport], reid: Mapping[str, Any], boxes: Mapping[str, int],
               duplicates: Mapping[str, Mapping[str, Mapping[str, int]]]) -> dict[str, Any]:
    """The comparison as plain data (``table.json``); ``duplicates``: {method: {region: {class: count}}}."""
    first = next(iter(reports.values()))
    classes = list(first.regions["all"].classes)
    pair_regions = [name for name in first.regions if name.startswith("overlap:")]
    return {
        "table_class": TABLE_CLASS,
        "classes": classes,
        "pair_regions": pair_regions,
        "units": {"AP": "%", "ATE": "m", "ASE": "% (1 - IoU)", "AOE": "rad"},
        "methods": list(reports),
        "boxes": dict(boxes),
        "regions": {region: {method: {name: class_figures(report, region, name) for name in classes}
                             for method, report in reports.items()}
                    for region in ["all", "overlap", *pair_regions]},
        "best_nms": best_thresholds(reports),
        "duplicates": {method: dict(by_region) for method, by_region in duplicates.items()},
        "reidentification": dict(reid),
        "paper_table_i": PAPER_TABLE_I,
    }


def figure_digits(column: str) -> int:
    """Decimals every table prints a figure of :data:`COLUMNS` to: AP and ASE (%) to 0.1, ATE and AOE to 0.001."""
    return 1 if column in ("AP", "ASE") else 3


def format_cell(value: float | None, column: str) -> str:
    """A figure of :data:`COLUMNS` as every table prints it (:func:`figure_digits`)."""
    return "-" if value is None else f"{value:.{figure_digits(column)}f}"


def table_markdown(table: Mapping[str, Any]) -> str:
    """``table.md``: Table I for the table's class, the paper's beside it, per-class AP, pairs, re-identification."""
    name, methods = table["table_class"], table["methods"]
    best = set(table["best_nms"].values())
    paper_methods = [m for m in PAPER_TABLE_I["All"] if m in methods]
    lines = [f"# Duplicate handling compared ({name}; AP and ASE in %, ATE in m, AOE in rad)", ""]
    if paper_methods:
        lines += ["Table I's layout, this evaluation above, the paper's (F-PointNets on the real nuScenes validation "
                  "set, for orientation only) below:", "",
                  "| Areas | " + " | ".join(f"{m} {c}" for m in paper_methods for c in COLUMNS) + " |",
                  "|---|" + "---|" * (len(paper_methods) * len(COLUMNS))]
        for region, label in REGIONS_SHOWN:
            figures = table["regions"][region]
            lines.append(f"| {label} | " + " | ".join(format_cell(figures[m][name][c], c) for m in paper_methods
                                                      for c in COLUMNS) + " |")
        for label, row in table["paper_table_i"].items():
            lines.append(f"| {label} (paper) | " + " | ".join(format_cell(v, c) for m in paper_methods
                                                              for v, c in zip(row[m], COLUMNS)) + " |")
    calibration = (table.get("thresholds") or {}).get("calibration")  # set by `sianms eval --thresholds-from`
    chosen = f"on the calibration split {calibration['split']}" if calibration else "over the split"
    lines += ["", f"Every method (NMS at IoU 0.3 unless named `@threshold`; *best* = best car AP of its family "
                  f"{chosen}):", "",
              "| method | " + " | ".join(f"{label} {c}" for _, label in REGIONS_SHOWN for c in COLUMNS) + " |",
              "|---|" + "---|" * (len(REGIONS_SHOWN) * len(COLUMNS))]
    for m in methods:
        cells = [format_cell(table["regions"][region][m][name][c], c) for region, _ in REGIONS_SHOWN for c in COLUMNS]
        lines.append(f"| {m}{' (best)' if m in best else ''} | " + " | ".join(cells) + " |")
    classes = table["classes"]
    lines += ["", f"AP (%) per class, boxes reported, and {name} duplicates left (false positives within 2 m of a "
                  "ground-truth box another prediction took):", "",
              "| method | boxes | " + " | ".join(f"{c} {label}" for c in classes for _, label in REGIONS_SHOWN)
              + " | " + " | ".join(f"duplicates {label}" for _, label in REGIONS_SHOWN) + " |",
              "|---|---|" + "---|" * (len(classes) * len(REGIONS_SHOWN) + len(REGIONS_SHOWN))]
    for m in methods:
        lines.append(f"| {m} | {table['boxes'][m]} | " + " | ".join(
            format_cell(table["regions"][region][m][c]["AP"], "AP") for c in classes for region, _ in REGIONS_SHOWN)
            + " | " + " | ".join(str(table["duplicates"][m][region][name]) for region, _ in REGIONS_SHOWN) + " |")
    pairs = table["pair_regions"]
    if pairs:
        lines += ["", f"{name} AP (%) per camera pair (overlap region):", "",
                  "| method | " + " | ".join(pair_label(p) for p in pairs) + " |",
                  "|---|" + "---|" * len(pairs)]
        for m in methods:
            pair_cells = " | ".join(format_cell(table["regions"][p][m][name]["AP"], "AP") for p in pairs)
            lines.append(f"| {m} | {pair_cells} |")
    if table["reidentification"]:
        lines += ["", "Re-identification against ground-truth identity (pairs to find: the oracle's):", "",
                  "| matcher | matched | correct | to find | precision | recall | F1 | "
                  + " | ".join(REID_WRONG_COLUMNS) + " |",
                  "|---|" + "---|" * (6 + len(REID_WRONG_COLUMNS))]
        for matcher, f in table["reidentification"].items():
            lines.append(f"| {matcher} | {f['pairs_matched']} | {f['pairs_correct']} | {f['pairs_true']} | "
                         f"{format_ratio(f['precision'])} | {format_ratio(f['recall'])} | {format_ratio(f['f1'])} | "
                         + " | ".join(reid_wrong_cells(f)) + " |")
    return "\n".join(lines) + "\n"


def reid_wrong_cells(figures: Mapping[str, Any]) -> list[str]:
    """What went wrong in a matcher's pairs (:func:`~sianms_cli.evaluation.finish.reidentification`);
    "-" for a figure an older evaluation did not record, or one the matcher has not (a gate)."""
    return [str(figures.get(name, "-")) for name in REID_WRONG_FIGURES]


def pair_label(region: str) -> str:
    """``overlap:CAM_FRONT|CAM_FRONT_RIGHT`` -> ``FRONT / FRONT_RIGHT`` (a bar would split a Markdown cell)."""
    return " / ".join(name.removeprefix("CAM_") for name in region.removeprefix("overlap:").split("|"))


def format_ratio(value: float | None) -> str:
    """A re-identification precision, recall or F1 to 0.001; ``-`` where undefined."""
    return "-" if value is None or not math.isfinite(value) else f"{value:.3f}"
