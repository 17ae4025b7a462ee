"""`sianms report`: one evaluation's Table I as Markdown, HTML and JSON; with a baseline, a regression gate.

Reads a complete `sianms eval` folder (``eval.json``, ``table.json``, ``metrics_<method>.json``,
``metrics_details_<method>.json``, ``pictures/``) and writes, into a report folder
(default ``EVAL/report/``):

- ``report.md`` and ``report.html`` (the same blocks, :mod:`.report_html`): Table I (car, All
  and Overlap, every method, the paper's numbers beside, ground-truth boxes per cell),
  re-identification, duplicates left, stage timings, the precision-recall and TP-error curves
  and the evaluation's bird's-eye pictures;
- ``report.json`` (``"schema": "sianms-report"``): self-contained, so a repository can commit
  it as the expected result of a CI run and pass it as ``--baseline``.

**The gate.** Given a baseline (another evaluation folder or a ``report.json``), every Table I
cell (region All / Overlap × the baseline's methods × AP, ATE, ASE, AOE) and each matcher's
re-identification precision, recall and F1 is compared. A cell *regresses* when AP (or a
re-identification figure) drops, or an error rises, by more than its allowance
(:data:`DEFAULT_ALLOWANCES`, ``--max-drop``), or when the baseline has a figure and this run
has none (a method no longer evaluated). A cell without a figure in both (no ground truth)
is fine. Runs are compared only when their :data:`COMPARABLE_FIELDS` and metrics config
agree; the fingerprints of the cache and checkpoints and ``dis_thr`` may differ, since those
are what a code change legitimately changes.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError
from sianms_cli.io import (RECORD_MAX_BYTES, build_folder, first_foreign_file, is_inside_working_folder, read_json,
                           real_path, snapshot, write_text)
from sianms_cli.json_stream import is_finite_number
from sianms_cli.progress import SILENT, Progress
from sianms_cli.reporting.eval_table import (
    COLUMNS,
    PAPER_TABLE_I,
    REGIONS_SHOWN,
    REID_WRONG_COLUMNS,
    REID_WRONG_FIGURES,
    format_cell,
    format_ratio,
    pair_label,
    reid_wrong_cells,
)
from sianms_cli.reporting.report_html import Block, Figure, Heading, Paragraph, Table, render_html, render_markdown

SCHEMA = "sianms-report"
RUNS_SCHEMA = "sianms-runs-report"  # runs_report's; either kind of report folder may be replaced by the other
SCHEMA_VERSION = 1
REPORT_FILE = "report.json"
MARKDOWN_FILE = "report.md"
HTML_FILE = "report.html"
PR_CURVES_FILE = "pr_curves.png"
TP_CURVES_FILE = "tp_curves.png"
REPORT_ENTRIES = frozenset({REPORT_FILE, MARKDOWN_FILE, HTML_FILE, PR_CURVES_FILE, TP_CURVES_FILE})
"""Every name either kind of report writes into its folder (runs_report: the first three), all plain files.
The folder is built in a staging folder beside it (io.build_folder), so nothing else, hidden or not, is ever
left inside it: any other entry is the user's and ``--overwrite`` must not delete it."""
DEFAULT_FOLDER = "report"  # inside the evaluation folder
EVAL_KIND = "sianms-eval"  # eval.json's "kind": sianms_cli.evaluation.job.KIND, not imported since job loads torch

DEFAULT_ALLOWANCES: Mapping[str, float] = MappingProxyType({
    "ap": 0.5,     # AP points (%): a drop of more than half a point regresses
    "ate": 0.02,   # metres of translation error
    "ase": 0.5,    # scale-error points (%, 1 - IoU)
    "aoe": 0.02,   # radians of orientation error
    "reid": 0.05,  # re-identification precision, recall, F1 (fractions)
})
ALLOWANCE_OF = {"AP": "ap", "ATE": "ate", "ASE": "ase", "AOE": "aoe"}
HIGHER_IS_BETTER = {"AP"}
REID_FIGURES = ("precision", "recall", "f1")
REID_COUNTS = ("pairs_matched", "pairs_correct", "pairs_true", *REID_WRONG_FIGURES)
COMPARABLE_FIELDS = ("split", "split_scenes", "dataset_sha256", "methods", "nms_sweep", "axis_mode", "sianms_classes",
                     "max_distance", "seed")
FINGERPRINT_FIELDS = ("dis_thr", "cache_sha256", "siamese_sha256", "fpointnet_sha256")
TABLE_FIELDS = ("table_class", "classes", "methods", "units", "boxes", "regions", "best_nms", "duplicates",
                "reidentification")
ROUNDING = 1e-9  # a change of exactly the allowance (0.35 - 0.33 in floats) is within it


def allowances_text() -> str:
    """The defaults as ``--max-drop`` takes them: ``ap=0.5,ate=0.02,...``."""
    return ",".join(f"{key}={value:g}" for key, value in DEFAULT_ALLOWANCES.items())


def parse_allowances(value: str | Mapping[str, float] | None) -> dict[str, float]:
    """Every allowance: :data:`DEFAULT_ALLOWANCES` with ``value``'s (``"ap=1,reid=0.1"`` or a mapping) on top.

    Raises SianmsError naming ``--max-drop`` and the bad key or value.
    """
    pairs: list[tuple[str, str | float]]
    if value is None or isinstance(value, str):
        items = [item.strip() for item in (value or "").split(",") if item.strip()]
        pairs = []
        for item in items:
            name, equals, text = item.partition("=")
            if not equals:
                raise SianmsError(f"--max-drop: '{item}' is not KEY=VALUE (keys: {', '.join(DEFAULT_ALLOWANCES)})")
            pairs.append((name.strip(), text.strip()))
    else:
        pairs = list(value.items())
    allowances = dict(DEFAULT_ALLOWANCES)
    seen = set()
    for key, number in pairs:
        if key not in DEFAULT_ALLOWANCES:
            raise SianmsError(f"--max-drop: unknown key '{key}'; expected {', '.join(DEFAULT_ALLOWANCES)}")
        if key in seen:
            raise SianmsError(f"--max-drop: '{key}' given twice")
        seen.add(key)
        try:
            allowance = float(number)
        except (TypeError, ValueError):
            allowance = math.nan
        if not (math.isfinite(allowance) and allowance >= 0) or isinstance(number, bool):
            raise SianmsError(f"--max-drop: {key}={number}: must be a number >= 0")
        allowances[key] = allowance
    return allowances


@dataclass(frozen=True, kw_only=True)
class ReportConfig:
    """What `sianms report` reads and how it judges a change.

    Attributes:
        eval: a complete `sianms eval` folder (``EVAL``).
        baseline: another evaluation folder or a ``report.json`` to compare with (``--baseline``).
        max_drop: allowances over :data:`DEFAULT_ALLOWANCES` (``--max-drop ap=0.5,ate=0.02``);
            normalised to every key.
        force: compare even when the comparable configs differ (``--force``).

    Raises SianmsError naming the flag for a value that cannot be right.
    """

    eval: str
    baseline: str | None = None
    max_drop: str | Mapping[str, float] | None = None
    force: bool = False

    def __post_init__(self) -> None:
        if not str(self.eval).strip():
            raise SianmsError("EVAL: must not be empty")
        object.__setattr__(self, "eval", str(self.eval))
        if self.baseline is not None:
            if not str(self.baseline).strip():
                raise SianmsError("--baseline: must not be empty")
            object.__setattr__(self, "baseline", str(self.baseline))
        given = [flag for flag, value in (("--max-drop", self.max_drop), ("--force", self.force)) if value]
        object.__setattr__(self, "max_drop", MappingProxyType(parse_allowances(self.max_drop)))
        if given and self.baseline is None:
            raise SianmsError(f"{given[0]}: applies to a comparison, and there is none without --baseline")


@dataclass(frozen=True)
class Report:
    """What one `sianms report` wrote: the folder, ``report.json``'s content and ``report.md``'s text."""

    out: Path
    content: dict[str, Any]
    markdown: str

    @property
    def regressions(self) -> list[dict[str, Any]]:
        """The cells beyond their allowance (empty without a baseline)."""
        return self.content.get("regressions", [])

    @property
    def html(self) -> Path:
        return self.out / HTML_FILE


# --------------------------------------------------------------------------- reading


def read_evaluation(folder: str | Path) -> dict[str, Any]:
    """The part of ``report.json`` one complete evaluation folder gives (no comparison).

    Raises:
        DataFormatError: naming the file and field: no ``eval.json``, another kind, not
        complete, or a ``table.json`` / ``metrics_<method>.json`` without what the report needs.
    """
    folder = Path(folder)
    marker_path = folder / "eval.json"
    if not folder.is_dir():
        raise DataFormatError(folder, "not a folder; EVAL is a `sianms eval` output folder")
    marker = _object(read_json(marker_path, RECORD_MAX_BYTES), marker_path, "")
    if marker.get("kind") != EVAL_KIND:
        raise DataFormatError(marker_path, f"not a sianms evaluation: expected '{EVAL_KIND}', got "
                                           f"{marker.get('kind')!r}", field="kind")
    if marker.get("complete") is not True:
        listed = marker.get("missing_scenes")
        missing = ", ".join(listed) if _names(listed) and listed else "none; the finish stage did not end"
        raise DataFormatError(marker_path, f"the evaluation is not complete (missing scenes: {missing}); "
                                           "finish it with `sianms eval`", field="complete")
    config = _check_config(_object(marker.get("config"), marker_path, "config"), marker_path, FINGERPRINT_FIELDS)
    table_path = folder / "table.json"
    table = _check_table(read_json(table_path, RECORD_MAX_BYTES), table_path)
    metrics_path = folder / f"metrics_{table['methods'][0]}.json"
    metrics_cfg = _object(_object(read_json(metrics_path, RECORD_MAX_BYTES), metrics_path, "").get("cfg"),
                          metrics_path, "cfg")
    for name in ("dist_th_tp", "min_recall"):  # the curves are drawn at these
        if not is_finite_number(metrics_cfg.get(name)):
            raise DataFormatError(metrics_path, "must be a number", field=f"cfg.{name}")
    timings = _timings(marker.get("timings", {}), marker_path)
    return strict_json({
        "schema": SCHEMA, "schema_version": SCHEMA_VERSION, "eval": str(folder),
        "config": {**{name: config[name] for name in COMPARABLE_FIELDS}, "metrics": metrics_cfg},
        "fingerprints": {name: config[name] for name in FINGERPRINT_FIELDS},
        **{name: table[name] for name in TABLE_FIELDS},
        "timings": dict(timings),
    })


def read_baseline(path: str | Path) -> dict[str, Any]:
    """A baseline: an evaluation folder (:func:`read_evaluation`) or a ``report.json`` (its comparison dropped)."""
    path = Path(path)
    if path.is_dir():
        return read_evaluation(path)
    content = _object(read_json(path, RECORD_MAX_BYTES), path, "")
    if content.get("schema") != SCHEMA:
        raise DataFormatError(path, f"not a sianms report: expected '{SCHEMA}', got {content.get('schema')!r}",
                              field="schema")
    if content.get("schema_version") != SCHEMA_VERSION:
        raise DataFormatError(path, f"this sianms reads version {SCHEMA_VERSION}, got "
                                    f"{content.get('schema_version')!r}", field="schema_version")
    _check_config(_object(content.get("config"), path, "config"), path, ("metrics",))
    _check_table(content, path)
    summary_keys = ("schema", "schema_version", "eval", "config", "fingerprints", *TABLE_FIELDS, "timings")
    for name in summary_keys:
        if name not in content:
            raise DataFormatError(path, "missing", field=name)
    if not isinstance(content["eval"], str):
        raise DataFormatError(path, "must be the evaluation folder's path", field="eval")
    _object(content["fingerprints"], path, "fingerprints")
    _timings(content["timings"], path)
    return {name: content[name] for name in summary_keys}


def _object(value: Any, path: Path, field: str) -> dict:
    if not isinstance(value, dict):
        raise DataFormatError(path, f"must be an object, got {type(value).__name__}", field=field or None)
    return value


def _timings(value: Any, path: Path) -> dict:
    for stage, seconds in _object(value, path, "timings").items():
        if not is_finite_number(seconds):
            raise DataFormatError(path, "must be a number of seconds", field=f"timings.{stage}")
    return value


CELL_RANGES = {"AP": (0.0, 100.0), "ASE": (0.0, 100.0), "ATE": (0.0, 1000.0), "AOE": (0.0, math.pi)}
"""What a Table I cell can hold: AP and ASE in %, ATE in metres (no evaluation matches boxes 1 km
apart), AOE in radians. A value beyond is an edit, and one near float's limit overflowed the spread
over runs."""


def _number_or_none(value: Any, low: float = -math.inf, high: float = math.inf) -> bool:
    return value is None or (is_finite_number(value) and low <= value <= high)


def _count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


CONFIG_TEXTS = ("split", "dataset_sha256", "axis_mode", "cache_sha256", "siamese_sha256", "fpointnet_sha256")
CONFIG_NAMES = ("split_scenes", "methods", "sianms_classes")


def _check_config(config: dict, path: Path, more: tuple[str, ...]) -> dict:
    """``config`` (eval.json's, or report.json's copy) holds the comparable fields and ``more``, those
    the reports print or pick runs apart by of the kind eval writes."""
    for name in COMPARABLE_FIELDS + more:
        if name not in config:
            raise DataFormatError(path, "missing", field=f"config.{name}")
        value = config[name]
        if name in CONFIG_TEXTS and not isinstance(value, str):
            raise DataFormatError(path, f"must be a string, got {type(value).__name__}", field=f"config.{name}")
        if name in CONFIG_NAMES and not _names(value):
            raise DataFormatError(path, "must be a list of names", field=f"config.{name}")
        if name == "seed" and not _count(value):
            raise DataFormatError(path, "must be a whole number >= 0", field="config.seed")
    return config


def _names(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(item, str) for item in value)


def _check_table(table: Any, path: Path) -> dict:
    """``table`` (table.json, or report.json's copy) holds every field and Table I cell the report reads."""
    table = _object(table, path, "")
    for name in TABLE_FIELDS:
        if name not in table:
            raise DataFormatError(path, "missing", field=name)
    methods, name = table["methods"], table["table_class"]
    if not isinstance(name, str):
        raise DataFormatError(path, "must be a class name", field="table_class")
    if not _names(table["classes"]):
        raise DataFormatError(path, "must be a list of class names", field="classes")
    if "pair_regions" in table and not _names(table["pair_regions"]):  # table.json's; report.json has none
        raise DataFormatError(path, "must be a list of region names", field="pair_regions")
    if not _names(methods) or not methods:
        raise DataFormatError(path, "must be a non-empty list of method names", field="methods")
    _object(table["units"], path, "units")
    for method, boxes in _object(table["boxes"], path, "boxes").items():
        if not _count(boxes):
            raise DataFormatError(path, "must be a whole number >= 0", field=f"boxes.{method}")
    regions = _object(table["regions"], path, "regions")
    for region, _ in REGIONS_SHOWN:
        for method in methods:
            field = f"regions.{region}.{method}.{name}"
            cell = _nested(regions, region, method, name)
            if not isinstance(cell, dict):
                raise DataFormatError(path, "missing", field=field)
            for column in COLUMNS:
                low, high = CELL_RANGES[column]
                if column not in cell or not _number_or_none(cell[column], low, high):
                    raise DataFormatError(path, f"must be a number in [{low:g}, {high:g}] or null",
                                          field=f"{field}.{column}")
            for column in ("gt", "pred"):
                if column not in cell or not _number_or_none(cell[column]):
                    raise DataFormatError(path, "must be a number or null", field=f"{field}.{column}")
    for family, method in _object(table["best_nms"], path, "best_nms").items():
        if method not in methods:
            raise DataFormatError(path, f"must be one of the methods, got {method!r}", field=f"best_nms.{family}")
    for method, by_region in _object(table["duplicates"], path, "duplicates").items():
        for region, counts in _object(by_region, path, f"duplicates.{method}").items():
            for class_name, count in _object(counts, path, f"duplicates.{method}.{region}").items():
                if not _count(count):
                    raise DataFormatError(path, "must be a whole number >= 0",
                                          field=f"duplicates.{method}.{region}.{class_name}")
    for matcher, figures in _object(table["reidentification"], path, "reidentification").items():
        for figure in REID_FIGURES:
            if not _number_or_none(_object(figures, path, f"reidentification.{matcher}").get(figure, "absent"), 0, 1):
                raise DataFormatError(path, "must be a number in [0, 1] or null",
                                      field=f"reidentification.{matcher}.{figure}")
        for figure in REID_COUNTS:  # shown as they are; an older evaluation may lack some
            if figure in figures and not _count(figures[figure]):
                raise DataFormatError(path, "must be a whole number >= 0", field=f"reidentification.{matcher}.{figure}")
    return table


def _nested(value: Any, *keys: str) -> Any:
    """``value[k1][k2]...``, or None where a level is missing or not an object."""
    for key in keys:
        if not isinstance(value, dict):
            return None
        value = value.get(key)
    return value


def strict_json(value: Any) -> Any:
    """``value`` with every NaN or infinity, however nested, as None: report.json is strict JSON."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {key: strict_json(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict_json(item) for item in value]
    return value


# --------------------------------------------------------------------------- comparing


def config_differences(now: Mapping[str, Any], baseline: Mapping[str, Any]) -> list[str]:
    """The comparable config fields (and ``metrics``) whose values differ."""
    return [name for name in COMPARABLE_FIELDS + ("metrics",)
            if now["config"].get(name) != baseline["config"].get(name)]


def judge(baseline: float | None, now: float | None, allowance: float, higher_is_better: bool) -> str | None:
    """Why a cell regressed, or None: a drop (or rise, for an error) beyond ``allowance``, or no figure now."""
    if baseline is None:
        return None
    if now is None:
        return "no figure now"
    worse = baseline - now if higher_is_better else now - baseline
    if worse > allowance + ROUNDING:
        return f"{'dropped' if higher_is_better else 'rose'} by {abs(now - baseline):.4g}"
    return None


def _row(region: str, method: str, metric: str, baseline: float | None, now: float | None, allowance: float,
         higher_is_better: bool) -> dict[str, Any]:
    why = judge(baseline, now, allowance, higher_is_better)
    return {"region": region, "method": method, "metric": metric, "baseline": baseline, "now": now,
            "difference": None if baseline is None or now is None else now - baseline,
            "allowance": allowance, "regressed": why is not None, "why": why}


def _figure(summary: Mapping[str, Any], region: str, method: str, column: str) -> float | None:
    """A Table I cell of a listed method (the only ones :func:`_check_table` checked), else None."""
    if method not in summary["methods"]:
        return None
    return summary["regions"][region].get(method, {}).get(summary["table_class"], {}).get(column)


def compare(now: Mapping[str, Any], baseline: Mapping[str, Any], allowances: Mapping[str, float]) -> dict[str, Any]:
    """Every Table I cell and re-identification figure, baseline beside now (module docstring)."""
    methods = list(baseline["methods"]) + [m for m in now["methods"] if m not in baseline["methods"]]
    cells = [_row(region, method, column, _figure(baseline, region, method, column),
                  _figure(now, region, method, column), allowances[ALLOWANCE_OF[column]], column in HIGHER_IS_BETTER)
             for region, _ in REGIONS_SHOWN for method in methods for column in COLUMNS]
    matchers = list(baseline["reidentification"]) + [m for m in now["reidentification"]
                                                     if m not in baseline["reidentification"]]
    reid = [_row("re-identification", matcher, figure, baseline["reidentification"].get(matcher, {}).get(figure),
                 now["reidentification"].get(matcher, {}).get(figure), allowances["reid"], True)
            for matcher in matchers for figure in REID_FIGURES]
    return {"cells": cells, "reidentification": reid}


# --------------------------------------------------------------------------- the document


def document(summary: Mapping[str, Any], comparison: Mapping[str, Any] | None, figures: list[Figure],
             notes: list[str]) -> list[Block]:
    """The report's blocks: the comparison first when there is one, then the run's own tables and figures."""
    blocks: list[Block] = []
    if comparison is not None:
        blocks += comparison_blocks(summary, comparison)
    blocks += table_i_blocks(summary)
    blocks += reid_blocks(summary) + duplicates_blocks(summary) + timing_blocks(summary)
    if figures or notes:
        blocks.append(Heading("Curves and pictures"))
    blocks += [Paragraph(note) for note in notes]
    blocks += figures
    return blocks


def table_i_blocks(summary: Mapping[str, Any]) -> list[Block]:
    name = summary["table_class"]
    best = set(summary["best_nms"].values())
    header = ["region", "method", *COLUMNS, *(f"paper {c}" for c in COLUMNS), "GT boxes", "predictions"]
    rows = []
    for region, label in REGIONS_SHOWN:
        for method in summary["methods"]:
            cell = summary["regions"][region][method][name]
            paper = PAPER_TABLE_I[label].get(method)
            rows.append([label, method + (" (best)" if method in best else ""),
                         *(format_cell(cell[c], c) for c in COLUMNS),
                         *(format_cell(paper[i] if paper else None, c) for i, c in enumerate(COLUMNS)),
                         str(cell["gt"]), str(cell["pred"])])
    return [Heading(f"Table I ({name})"),
            Paragraph(f"AP and ASE in %, ATE in m, AOE in rad. The paper's figures (F-PointNets on the real nuScenes "
                      "validation set) are beside for orientation only; GT boxes is the number of ground-truth "
                      f"{name}s the cell is measured on. NMS runs at IoU 0.3 unless named `@threshold`; *best* = "
                      "best car AP of its family over the split."),
            Table("table-i", header, rows, labels=2)]


def reid_blocks(summary: Mapping[str, Any]) -> list[Block]:
    reid = summary["reidentification"]
    if not reid:
        return []
    rows = [[matcher, str(f.get("pairs_matched", "-")), str(f.get("pairs_correct", "-")), str(f.get("pairs_true", "-")),
             format_ratio(f["precision"]), format_ratio(f["recall"]), format_ratio(f["f1"]),
             *reid_wrong_cells(f)] for matcher, f in reid.items()]
    return [Heading("Re-identification"),
            Paragraph("Against ground-truth identity; the pairs to find are the oracle's. A wrong match has "
                      "\"no true partner\" when neither of its detections has its own object among the other "
                      "camera's candidates (only the distance threshold could have refused it); else it passed a "
                      "true partner over. gated-sianms (ours, not the paper's) keeps a siaNMS match only where its two "
                      "detections' own single-camera boxes overlap in bird's-eye view."),
            Table("reidentification", ["matcher", "matched", "correct", "to find", "precision", "recall", "F1",
                                       *REID_WRONG_COLUMNS], rows)]


def duplicates_blocks(summary: Mapping[str, Any]) -> list[Block]:
    name = summary["table_class"]
    duplicates = summary["duplicates"]
    regions = [region for region in summary["regions"] if all(region in duplicates.get(m, {})
                                                             for m in summary["methods"])]
    labels = dict(REGIONS_SHOWN)
    header = ["method", *(labels.get(region) or pair_label(region) for region in regions)]
    rows = [[method, *(str(duplicates[method][region].get(name, "-")) for region in regions)]
            for method in summary["methods"]]
    return [Heading(f"Duplicates left ({name})"),
            Paragraph("False positives at 2 m with a ground-truth box of their class within 2 m that another "
                      "prediction took, per region (camera pairs by their overlap)."),
            Table("duplicates", header, rows)]


def timing_blocks(summary: Mapping[str, Any]) -> list[Block]:
    timings = summary["timings"]
    total = sum(timings.values())
    if not timings or total <= 0:
        return []
    rows = [[stage.removesuffix("_s"), f"{seconds:.2f}", f"{100 * seconds / total:.1f} %"]
            for stage, seconds in sorted(timings.items(), key=lambda item: -item[1])]
    rows.append(["total", f"{total:.2f}", "100.0 %"])
    return [Heading("Stage timings"), Paragraph("Longest first, from eval.json (a resumed run counts only its own "
                                                "scenes)."),
            Table("timings", ["stage", "seconds", "share"], rows)]


def _difference(value: float | None, column: str) -> str:
    if value is None:
        return "-"
    return f"{value:+.1f}" if column in ("AP", "ASE") else f"{value:+.3f}"


def comparison_blocks(summary: Mapping[str, Any], comparison: Mapping[str, Any]) -> list[Block]:
    """The verdict, the regressed cells, then per region baseline / now / difference side by side."""
    regressions = [row for row in comparison["cells"] + comparison["reidentification"] if row["regressed"]]
    baseline = comparison["baseline"]
    blocks: list[Block] = [Heading("Against the baseline")]
    verdict = (f"**{len(regressions)} regression(s)** beyond the allowances" if regressions
               else "No regression beyond the allowances")
    allowances = ", ".join(f"{key} {value:g}" for key, value in comparison["allowances"].items())
    origin = "" if baseline["eval"] == baseline["source"] else f" (evaluation `{baseline['eval']}`)"
    blocks.append(Paragraph(f"{verdict}. Baseline: `{baseline['source']}`{origin}. Allowances: {allowances} (AP and "
                            "ASE in points, ATE in m, AOE in rad, re-identification as a fraction)."))
    if comparison["config_differences"]:
        blocks.append(Paragraph("Compared with `--force` although the configs differ in: "
                                + ", ".join(comparison["config_differences"]) + "."))
    if comparison["fingerprints_changed"]:
        blocks.append(Paragraph("Changed since the baseline: " + ", ".join(comparison["fingerprints_changed"]) + "."))
    if regressions:
        blocks.append(Table("regressions", ["region", "method", "metric", "baseline", "now", "allowance", "why"],
                            [[row["region"], row["method"], row["metric"], _value(row["baseline"], row["metric"]),
                              _value(row["now"], row["metric"]), f"{row['allowance']:g}", row["why"]]
                             for row in regressions], labels=3))
    name = summary["table_class"]
    header = ["method", *(f"{c} {side}" for c in COLUMNS for side in ("base", "now", "diff"))]
    for region, label in REGIONS_SHOWN:
        rows, marked = [], set()
        methods = list(dict.fromkeys(row["method"] for row in comparison["cells"]))
        for i, method in enumerate(methods):
            row = [method]
            for j, column in enumerate(COLUMNS):
                cell = next(c for c in comparison["cells"]
                            if (c["region"], c["method"], c["metric"]) == (region, method, column))
                row += [format_cell(cell["baseline"], column), format_cell(cell["now"], column),
                        _difference(cell["difference"], column)]
                if cell["regressed"]:
                    marked.update({(i, 2 + 3 * j), (i, 3 + 3 * j)})
            rows.append(row)
        blocks += [Paragraph(f"**{label}** ({name}):"),
                   Table(f"compare-{region}", header, rows, frozenset(marked))]
    if comparison["reidentification"]:
        rows, marked = [], set()
        for i, row in enumerate(comparison["reidentification"]):
            rows.append([row["method"], row["metric"], format_ratio(row["baseline"]), format_ratio(row["now"]),
                         "-" if row["difference"] is None else f"{row['difference']:+.3f}"])
            if row["regressed"]:
                marked.add((i, 3))
        blocks += [Paragraph("**Re-identification**:"),
                   Table("compare-reidentification", ["matcher", "figure", "base", "now", "diff"], rows,
                         frozenset(marked), labels=2)]
    return blocks


def _value(value: float | None, metric: str) -> str:
    return format_cell(value, metric) if metric in COLUMNS else format_ratio(value)


def regression_lines(regressions: list[Mapping[str, Any]]) -> list[str]:
    """One line per regressed cell: region, method, metric, baseline, now, allowance and why."""
    return [f"{row['region']} {row['method']} {row['metric']}: baseline {_value(row['baseline'], row['metric'])}, "
            f"now {_value(row['now'], row['metric'])}, allowance {row['allowance']:g} ({row['why']})"
            for row in regressions]


# --------------------------------------------------------------------------- figures


def draw_figures(folder: Path, summary: Mapping[str, Any], eval_folder: Path,
                 out: Path) -> tuple[list[Figure], list[str]]:
    """``pr_curves.png`` and ``tp_curves.png`` in ``folder`` from the evaluation's metrics_details files,
    and the evaluation's bird's-eye pictures; a note where something could not be drawn."""
    from sianms_cli.metrics.evaluate import detail_key, read_details
    from sianms_cli.reporting.eval_pictures import draw_pr_curves, draw_tp_curves

    name, cfg = summary["table_class"], summary["config"]["metrics"]
    regions = tuple(region for region, _ in REGIONS_SHOWN)
    paths = {method: eval_folder / f"metrics_details_{method}.json" for method in summary["methods"]}
    figures, notes = [], []
    missing = [path.name for path in paths.values() if not path.is_file()]
    if missing:
        notes.append(f"No curves: the evaluation has no {missing[0]} (written by `sianms eval` since metrics_details "
                     "replaced curves.json); rerun the evaluation to draw them.")
    else:
        key = detail_key(name, cfg["dist_th_tp"])
        curves = {}
        for method, path in paths.items():
            details = read_details(path)
            for region in regions:
                if key not in details.get(region, {}):
                    raise DataFormatError(path, "missing", field=f"{region}.{key}")
            curves[method] = {region: details[region][key] for region in regions}
        draw_pr_curves(folder / PR_CURVES_FILE, curves, name, regions)
        draw_tp_curves(folder / TP_CURVES_FILE, curves, name, regions, cfg["min_recall"])
        figures += [Figure(f"Precision against recall, {name} at {cfg['dist_th_tp']} m, per method",
                           folder / PR_CURVES_FILE, PR_CURVES_FILE),
                    Figure(f"TP errors against recall, {name} at {cfg['dist_th_tp']} m (the reported error is the "
                           f"mean right of recall {cfg['min_recall']})", folder / TP_CURVES_FILE, TP_CURVES_FILE)]
    for picture in sorted((eval_folder / "pictures").glob("*.png")):
        figures.append(Figure(f"Bird's-eye view of sample {picture.stem}, one panel per method", picture,
                              os.path.relpath(real_path(picture), real_path(out))))
    return figures, notes


# --------------------------------------------------------------------------- the command


def is_report_folder(folder: Path) -> bool:
    """Whether ``folder`` holds a ``report.json`` of a report's schema (so ``--overwrite`` may replace it)."""
    try:
        content = read_json(folder / REPORT_FILE)
    except DataFormatError:
        return False
    return isinstance(content, dict) and content.get("schema") in (SCHEMA, RUNS_SCHEMA)


def foreign_entry(folder: Path) -> Path | None:
    """The first entry of ``folder`` (by name) that no report writes (:data:`REPORT_ENTRIES`, plain files; a
    link or a folder never is), or None when every entry is a report's."""
    return first_foreign_file(folder, lambda entry: entry.name in REPORT_ENTRIES)


def check_output(out: Path, overwrite: bool) -> None:
    """Refuse ``out`` unless it is new, empty, or (with ``overwrite``) a report folder holding nothing
    but what a report writes (:func:`foreign_entry`): replacing it deletes every entry."""
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out} exists and is not a folder; choose another --out")
    if out.is_symlink():  # replacing it would put a folder where the link was and leave the link beside it
        raise OutputExistsError(f"{out} is a link; give the folder it points to, or another --out")
    if not out.is_dir() or not any(out.iterdir()):
        return
    if not is_report_folder(out):
        raise OutputExistsError(f"{out} is not empty and is not a sianms report (no {REPORT_FILE} of schema "
                                f"'{SCHEMA}' or '{RUNS_SCHEMA}'); choose another --out")
    foreign = foreign_entry(out)
    if foreign is not None:
        raise OutputExistsError(f"{out}: not replaced: '{foreign.name}' is not something sianms report writes; "
                                "remove it yourself or choose another --out")
    if not overwrite:
        raise OutputExistsError(f"{out} holds a report; pass --overwrite to replace it")
    if is_inside_working_folder(out):
        raise OutputExistsError(f"{out} is the current folder or one of its parents; choose another --out")


def write_report_files(folder: Path, title: str, blocks: list[Block], content: Mapping[str, Any]) -> str:
    """``report.json`` (``content``), ``report.md`` and ``report.html`` (``blocks``) into ``folder``;
    returns the Markdown."""
    markdown = render_markdown(title, blocks)
    write_text(folder / REPORT_FILE, json.dumps(content, indent=2, allow_nan=False) + "\n")
    write_text(folder / MARKDOWN_FILE, markdown)
    write_text(folder / HTML_FILE, render_html(title, blocks))
    return markdown


def run(config: ReportConfig, out: str | Path | None = None, *, overwrite: bool = False,
        progress: Progress = SILENT) -> Report:
    """`sianms report` (module docstring): read, compare, draw and write the report folder atomically.

    Args:
        config: the evaluation, the baseline and the allowances.
        out: the report folder (default ``EVAL/report``); replaced only with ``overwrite`` and
            only when it is a report folder.
        progress: told of the steps (read, compare, draw, write).

    Raises:
        DataFormatError: EVAL or the baseline is not what it should be.
        SianmsError: the comparable configs differ and ``config.force`` is false.
        OutputExistsError: ``out`` may not be replaced.
    """
    eval_folder = Path(config.eval)
    out = Path(out) if out is not None else eval_folder / DEFAULT_FOLDER
    check_output(out, overwrite)
    seen = snapshot(out)  # publishing refuses an out that changed meanwhile
    progress.start(4, "step", "report")
    summary = read_evaluation(eval_folder)
    content: dict[str, Any] = dict(summary)
    comparison = None
    if config.baseline is not None:
        baseline = read_baseline(config.baseline)
        if baseline["table_class"] != summary["table_class"]:  # not a config difference --force may pass over
            raise DataFormatError(config.baseline, f"Table I of {baseline['table_class']!r} where {eval_folder}'s "
                                                   f"is of {summary['table_class']!r}: no cell compares",
                                  field="table_class")
        differing = config_differences(summary, baseline)
        allowances = config.max_drop
        assert isinstance(allowances, Mapping)  # ReportConfig.__post_init__ resolved it to every allowance
        if differing and not config.force:
            raise SianmsError(f"--baseline: {config.baseline} was evaluated with another config (differs in: "
                              f"{', '.join(differing)}); pass --force to compare anyway")
        comparison = {
            "baseline": {"source": config.baseline, "eval": baseline["eval"], "fingerprints": baseline["fingerprints"]},
            "allowances": dict(allowances), "forced": config.force, "config_differences": differing,
            "fingerprints_changed": [name for name in FINGERPRINT_FIELDS
                                     if summary["fingerprints"].get(name) != baseline["fingerprints"].get(name)],
            **compare(summary, baseline, allowances)}
        content["comparison"] = comparison
        content["regressions"] = [{key: row[key] for key in ("region", "method", "metric", "baseline", "now",
                                                             "allowance", "why")}
                                  for row in comparison["cells"] + comparison["reidentification"] if row["regressed"]]
    progress.advance()
    content = strict_json(content)

    def write(staging: Path) -> str:
        figures, notes = draw_figures(staging, summary, eval_folder, out)
        progress.advance()
        markdown = write_report_files(staging, f"sianms report: {summary['eval']}",
                                      document(summary, comparison, figures, notes), content)
        progress.advance()
        return markdown

    published, markdown = build_folder(out, write, seen)
    progress.advance()
    return Report(published, content, markdown)
