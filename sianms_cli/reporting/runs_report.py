"""`sianms report EVAL EVAL ...`: Table I over several runs (seeds), with its spread, and the paired
differences that rank the methods.

One run's Table I cannot rank methods whose figures differ by less than what another seed
moves them. Runs of the same settings on other seeds (``sianms demo --seed S``) give the
spread; and since the methods of one run share its data, detector and matcher, the
*paired* difference of two methods, run by run, varies far less than either method's
figure, so it is what ranks them. Every run is an evaluation folder or the ``report.json``
`sianms report` wrote for it (what a study keeps once its 8 GB folders are gone).

Written into ``--out`` (built in a hidden staging folder, moved into place when complete):

- ``report.md`` / ``report.html``: the runs; Table I (car) over the runs as mean ± sample
  standard deviation, an NMS family also at each run's best threshold, the paper's figures
  beside and the ground-truth cars of each run; the paired differences of the merging methods
  (siaNMS, hybrid, gated siaNMS, oracle) against vanilla and Axis-NMS in both regions, with a
  95 % Student-t interval of the mean difference and the number of runs where the method did
  better; re-identification over the runs.
- ``report.json`` (``"schema": "sianms-runs-report"``): the same figures, and each run's value
  of every cell and difference.

With runs of a second arm (``--paired-with``: the same worlds evaluated with another detector or
siamese network, as a study's second arm is), each method's figures are also compared between the
arms, world by world: these runs minus the runs on the same dataset and seed, with the same
interval and count. A method "(best)" takes each arm's own best threshold, chosen as that arm's
runs chose it.

The runs must have been evaluated alike (:data:`SHARED_FIELDS`: the same methods, NMS sweep,
classes, distance and metrics config); their datasets and seeds differ, as a study's do. The
same run given twice would fake a spread and is refused.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.io import RECORD_MAX_BYTES, build_folder, read_json, snapshot
from sianms_cli.json_stream import is_finite_number
from sianms_cli.progress import SILENT, Progress
from sianms_cli.reporting.eval_table import (
    COLUMNS,
    PAPER_TABLE_I,
    REGIONS_SHOWN,
    figure_digits,
    format_cell,
    format_ratio,
)
from sianms_cli.reporting.report import (
    HIGHER_IS_BETTER,
    REID_FIGURES,
    RUNS_SCHEMA,
    Report,
    check_output,
    read_baseline,
    strict_json,
    write_report_files,
)
from sianms_cli.reporting.report_html import Block, Heading, Paragraph, Table

SCHEMA_VERSION = 1
SHARED_FIELDS = ("split", "methods", "nms_sweep", "axis_mode", "sianms_classes", "max_distance", "metrics")
RUN_IDENTITY = ("dataset_sha256", "seed")  # with the fingerprints: what tells two runs apart
MERGING_METHODS = ("sianms", "hybrid", "gated-sianms", "oracle")
REFERENCES = ("vanilla", "axis-nms", "axis-nms (best)")
BEST = " (best)"
CONFIDENCE = 0.95


@dataclass(frozen=True)
class RunsReportConfig:
    """The runs `sianms report` summarises: two or more evaluation folders or their ``report.json``; and the
    runs of a second arm on the same worlds to compare them with (none, or one per run)."""

    evals: tuple[str, ...]
    paired_with: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        evals = tuple(str(source) for source in self.evals)
        if len(evals) < 2:
            raise SianmsError("EVAL: a spread over runs needs at least two; one EVAL gets its own report")
        if any(not source.strip() for source in evals):
            raise SianmsError("EVAL: must not be empty")
        paired_with = tuple(str(source) for source in self.paired_with)
        if paired_with and len(paired_with) != len(evals):
            raise SianmsError(f"--paired-with: {len(paired_with)} runs for {len(evals)} EVAL; give one run of the "
                              "other arm for each EVAL")
        if any(not source.strip() for source in paired_with):
            raise SianmsError("--paired-with: must not be empty")
        object.__setattr__(self, "evals", evals)
        object.__setattr__(self, "paired_with", paired_with)


# --------------------------------------------------------------------------- reading


def read_runs(sources: Sequence[str]) -> list[dict[str, Any]]:
    """Each run's report summary (:func:`report.read_baseline`), checked to be distinct runs evaluated alike.

    Raises:
        DataFormatError: a source is not a complete evaluation or a report.json.
        SianmsError: two runs differ in a :data:`SHARED_FIELDS` field, or one run is given twice.
    """
    runs = [read_baseline(source) for source in sources]
    first = runs[0]
    for source, run in zip(sources[1:], runs[1:]):
        differing = [name for name in SHARED_FIELDS if run["config"].get(name) != first["config"].get(name)]
        if run["methods"] != first["methods"] and "methods" not in differing:  # table.json's own list
            differing.append("the methods of table.json")
        if differing:
            raise SianmsError(f"EVAL: {source} was evaluated otherwise than {sources[0]} (differs in: "
                              f"{', '.join(differing)}); a spread is taken over runs evaluated alike")
    seen: dict[tuple, str] = {}
    for source, run in zip(sources, runs):
        identity = (*world_of(run), json.dumps(run["fingerprints"], sort_keys=True))
        if identity in seen:
            raise SianmsError(f"EVAL: {source} is the same run as {seen[identity]} (same dataset, seed, cache and "
                              "checkpoints); each run may count once")
        seen[identity] = source
    return runs


def world_of(run: Mapping[str, Any]) -> tuple[str, ...]:
    """The world a run evaluated: its dataset and seed (:data:`RUN_IDENTITY`), as comparable text."""
    return tuple(json.dumps(run["config"][name]) for name in RUN_IDENTITY)


def read_paired_runs(sources: Sequence[str], runs: Sequence[Mapping[str, Any]],
                     paired_sources: Sequence[str]) -> tuple[list[str], list[dict[str, Any]]]:
    """The second arm's runs (:func:`read_runs`), put in the order of ``runs``: each on the same dataset and seed.

    Raises:
        DataFormatError: a source is not a complete evaluation or a report.json.
        SianmsError: the arms were evaluated otherwise, a run has no counterpart on its world, or a counterpart
            is the same run (same cache and checkpoints: nothing differs between the arms).
    """
    others = read_runs(paired_sources)
    differing = [name for name in SHARED_FIELDS if others[0]["config"].get(name) != runs[0]["config"].get(name)]
    if differing:
        raise SianmsError(f"--paired-with: {paired_sources[0]} was evaluated otherwise than {sources[0]} (differs "
                          f"in: {', '.join(differing)}); arms are compared when evaluated alike")
    world = {world_of(run): i for i, run in enumerate(others)}
    order = []
    for source, run in zip(sources, runs):
        i = world.pop(world_of(run), None)
        if i is None:
            raise SianmsError(f"--paired-with: no run on the dataset and seed of {source} (dataset "
                              f"{str(run['config']['dataset_sha256'])[:12]}, seed {run['config']['seed']}); each "
                              "EVAL is compared with the other arm's run on the same world")
        if others[i]["fingerprints"] == run["fingerprints"]:
            raise SianmsError(f"--paired-with: {paired_sources[i]} is the same run as {source} (same cache and "
                              "checkpoints); the arms must differ")
        order.append(i)
    return [paired_sources[i] for i in order], [others[i] for i in order]


def run_thresholds(source: str) -> dict[str, Any] | None:
    """The thresholds an evaluation folder used and where each came from (its table.json's ``thresholds``,
    :func:`~sianms_cli.evaluation.calibration.thresholds_used`); None for a report.json or an evaluation from
    before they were recorded."""
    path = Path(source) / "table.json"
    if not Path(source).is_dir():
        return None
    value = read_json(path, RECORD_MAX_BYTES).get("thresholds")
    if value is None:
        return None
    dis_thr = value.get("dis_thr") if isinstance(value, dict) else None
    if not (isinstance(dis_thr, dict) and _number_or_none(dis_thr.get("value"))
            and isinstance(dis_thr.get("source"), str)):
        raise DataFormatError(path, "must hold a value (a number or null) and its source", field="thresholds.dis_thr")
    nms = value.get("nms")
    if not isinstance(nms, dict) or not all(isinstance(choice, dict) and isinstance(choice.get("method"), str)
                                            and isinstance(choice.get("source"), str) for choice in nms.values()):
        raise DataFormatError(path, "must map each NMS family to its method and source", field="thresholds.nms")
    calibration = value.get("calibration")
    if calibration is not None and not (isinstance(calibration, dict) and all(
            isinstance(calibration.get(key), str) for key in ("path", "split", "sha256"))):
        raise DataFormatError(path, "must be null or hold the calibration's path, split and sha256",
                              field="thresholds.calibration")
    return {"dis_thr": {"value": dis_thr["value"], "source": dis_thr["source"]},
            "nms": {family: {"method": choice["method"], "source": choice["source"]} for family, choice in nms.items()},
            "calibration": None if calibration is None else {key: calibration[key] for key in ("path", "split",
                                                                                                 "sha256")},
            "own_split": own_split_choices(Path(source) / "thresholds.json")}


def own_split_choices(path: Path) -> dict[str, Any] | None:
    """What the evaluated split's own labels choose (its thresholds.json, used by no table of its own):
    {dis_thr, nms: {family: method}}; None where the evaluation has no such file."""
    if not path.is_file():
        return None
    record = read_json(path, RECORD_MAX_BYTES)
    dis_thr = record.get("dis_thr") if isinstance(record, dict) else None
    if not (isinstance(dis_thr, dict) and _number_or_none(dis_thr.get("value"))):
        raise DataFormatError(path, "must hold a value, a number or null", field="dis_thr")
    nms = record.get("nms")
    if not (isinstance(nms, dict) and all(isinstance(choice, dict) and isinstance(choice.get("method"), str)
                                          for choice in nms.values())):
        raise DataFormatError(path, "must map each NMS family to its method", field="nms")
    return {"dis_thr": dis_thr["value"], "nms": {family: choice["method"] for family, choice in nms.items()}}


def _number_or_none(value: Any) -> bool:
    return value is None or is_finite_number(value)


# --------------------------------------------------------------------------- statistics


def spread(values: Sequence[float | None]) -> dict[str, Any]:
    """Mean, sample standard deviation and 95 % Student-t interval of the mean over the runs with a figure.

    ``values`` keeps one entry per run (None where a run has no figure there); the statistics
    use the others, ``n`` says how many. With one figure there is no spread (sd and interval None).
    """
    from scipy.stats import t

    present = np.array([v for v in values if v is not None], dtype=float)
    n = len(present)
    mean = float(present.mean()) if n else None
    sd = float(present.std(ddof=1)) if n >= 2 else None
    half = None if sd is None else float(t.ppf(0.5 + CONFIDENCE / 2, n - 1) * sd / math.sqrt(n))
    interval = None if half is None or mean is None else [mean - half, mean + half]  # a half needs n >= 2
    return {"mean": mean, "sd": sd, "ci95": interval, "n": n,
            "values": list(values)}


def method_rows(runs: Sequence[Mapping[str, Any]]) -> list[str]:
    """Table I's rows: every method, and each NMS family again at its best threshold in each run."""
    methods = list(runs[0]["methods"])
    best = [family + BEST for family in runs[0]["best_nms"] if all(family in run["best_nms"] for run in runs)]
    rows = []
    for method in methods:
        rows.append(method)
        rows += [family for family in best if family == method + BEST]
    return rows


def figure(run: Mapping[str, Any], region: str, method: str, column: str) -> float | None:
    """One run's figure of a Table I cell; ``"<family> (best)"`` reads that run's best threshold of the family."""
    if method.endswith(BEST):
        method = run["best_nms"][method.removesuffix(BEST)]
    return run["regions"][region][method][run["table_class"]][column]


def table_cells(runs: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, dict[str, Any]]]:
    """{region: {method: {column: spread}}} for every Table I cell, and the ground-truth cars per run."""
    return {region: {method: {**{column: spread([figure(run, region, method, column) for run in runs])
                                 for column in COLUMNS},
                              "gt": [figure(run, region, method, "gt") for run in runs]}
                     for method in method_rows(runs)}
            for region, _ in REGIONS_SHOWN}


def difference(pairs: Sequence[tuple[float | None, float | None]], column: str) -> dict[str, Any]:
    """The spread of ``a - b`` over the runs' ``(a, b)`` figures of ``column``, and ``better``: the runs where
    ``a`` did better (higher AP, lower errors), ties counting neither way. A run without both figures is
    left out (None)."""
    differences = [None if a is None or b is None else a - b for a, b in pairs]
    sign = 1.0 if column in HIGHER_IS_BETTER else -1.0
    return {**spread(differences), "better": sum(1 for d in differences if d is not None and sign * d > 0)}


def paired_differences(runs: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Each merging method minus each reference, run by run, per region and column (:func:`difference`)."""
    rows = method_rows(runs)
    out = []
    for method in (m for m in MERGING_METHODS if m in rows):
        for reference in (r for r in REFERENCES if r in rows):
            for region, _ in REGIONS_SHOWN:
                entry: dict[str, Any] = {"method": method, "reference": reference, "region": region}
                for column in COLUMNS:
                    entry[column] = difference([(figure(run, region, method, column),
                                                 figure(run, region, reference, column)) for run in runs], column)
                out.append(entry)
    return out


def arm_differences(runs: Sequence[Mapping[str, Any]], others: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Each method's figures in ``runs`` minus those of ``others`` (the other arm, run i on run i's world), per
    region and column (:func:`difference`), for the methods both arms have."""
    other_rows = method_rows(others)
    out = []
    for method in (m for m in method_rows(runs) if m in other_rows):
        for region, _ in REGIONS_SHOWN:
            entry: dict[str, Any] = {"method": method, "region": region}
            for column in COLUMNS:
                entry[column] = difference([(figure(run, region, method, column), figure(other, region, method, column))
                                            for run, other in zip(runs, others)], column)
            out.append(entry)
    return out


def reidentification(runs: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """Each matcher every run evaluated: precision, recall and F1 over the runs, true pairs per run."""
    evaluated = [m for m in runs[0]["reidentification"] if all(m in run["reidentification"] for run in runs)]
    matchers = sorted(evaluated,
                      key=lambda m: runs[0]["methods"].index(m) if m in runs[0]["methods"] else len(evaluated))
    return {matcher: {**{name: spread([run["reidentification"][matcher].get(name) for run in runs])
                         for name in REID_FIGURES},
                      "pairs_true": [run["reidentification"][matcher].get("pairs_true") for run in runs]}
            for matcher in matchers}


# --------------------------------------------------------------------------- the document


def _signed(value: float, digits: int) -> str:
    """``value`` with its sign, and no "-0.0" for a difference that rounds to nothing."""
    text = f"{value:+.{digits}f}"
    return f"{0.0:+.{digits}f}" if float(text) == 0 else text


def _plus_minus(stats: Mapping[str, Any], column: str, signed: bool = False) -> str:
    if stats["mean"] is None:
        return "-"
    digits = figure_digits(column)
    mean = _signed(stats["mean"], digits) if signed else f"{stats['mean']:.{digits}f}"
    return mean if stats["sd"] is None else f"{mean} ± {stats['sd']:.{digits}f}"


def _interval(stats: Mapping[str, Any], column: str) -> str:
    if stats["ci95"] is None:
        return "-"
    low, high = stats["ci95"]
    digits = figure_digits(column)
    return f"[{_signed(low, digits)}, {_signed(high, digits)}]"


def document(content: Mapping[str, Any]) -> list[Block]:
    """The runs report's blocks: the runs, then :func:`result_blocks`."""
    runs = content["runs"]
    return [Heading(f"{len(runs)} runs"),
            Table("runs", ["run", "source", "seed", "dataset", "GT cars, all", "GT cars, overlap"],
                  [[str(i), run["source"], str(run["seed"]), run["dataset_sha256"][:12], str(run["gt"]["all"]),
                    str(run["gt"]["overlap"])] for i, run in enumerate(runs)], labels=2),
            *result_blocks(content)]


def best_note(runs: Sequence[Mapping[str, Any]]) -> str:
    """What `(best)` means for these runs: chosen on a calibration split (``--thresholds-from``) or on their own."""
    calibrated = [run.get("thresholds") is not None and run["thresholds"].get("calibration") is not None
                  for run in runs]
    if all(calibrated):
        return ("`(best)`: the family at the threshold with the best car AP on each run's calibration split "
                "(`sianms eval --thresholds-from`), never chosen on the split reported here.")
    if any(calibrated):
        return ("`(best)`: the family at the threshold with the best car AP on a calibration split for the runs that "
                "took their thresholds from one, on the reported split itself for the others.")
    return ("`(best)`: the family at the threshold with the best car AP of each run, chosen on the split reported "
            "here, which may differ between runs.")


def result_blocks(content: Mapping[str, Any], json_name: str = "report.json") -> list[Block]:
    """Table I over the runs, the paired differences and re-identification; ``json_name``: the file holding
    every run's figures."""
    runs, name = content["runs"], content["table_class"]
    n = len(runs)
    blocks: list[Block] = []
    header = ["region", "method", *COLUMNS, *(f"paper {c}" for c in COLUMNS), "GT boxes per run"]
    rows = []
    for region, label in REGIONS_SHOWN:
        for method, cells in content["cells"][region].items():
            paper = PAPER_TABLE_I[label].get(method)
            rows.append([label, method, *(_plus_minus(cells[c], c) for c in COLUMNS),
                         *(format_cell(paper[i] if paper else None, c) for i, c in enumerate(COLUMNS)),
                         ", ".join(str(gt) for gt in cells["gt"])])
    blocks += [Heading(f"Table I over the runs ({name})"),
               Paragraph(f"Mean ± sample standard deviation over the {n} runs (AP and ASE in %, ATE in m, AOE in "
                         f"rad). {best_note(runs)} The paper's figures (F-PointNets on the real nuScenes validation "
                         "set) are beside for orientation only."),
               Table("table-i", header, rows, labels=2)]
    header = ["comparison", "region", *(f"{c} difference" for c in COLUMNS), "AP 95 % interval", "AP better in"]
    rows = []
    for entry in content["paired_differences"]:
        ap = entry["AP"]
        rows.append([f"{entry['method']} − {entry['reference']}", dict(REGIONS_SHOWN)[entry["region"]],
                     *(_plus_minus(entry[c], c, signed=True) for c in COLUMNS), _interval(ap, "AP"),
                     f"{ap['better']} of {ap['n']}"])
    if rows:
        blocks += [Heading("Paired differences"),
                   Paragraph("A method minus a reference in each run, then mean ± sample standard deviation over "
                             "the runs: the methods of one run share its data, detector and matcher, so this is what "
                             "ranks them. The interval is the 95 % Student-t interval of the mean difference; "
                             "*better in* counts the runs where the method's AP was higher. Each run's differences, "
                             f"and the intervals of the error columns, are in {json_name}."),
                   Table("paired-differences", header, rows, labels=2)]
    blocks += arm_blocks(content, json_name)
    reid = content["reidentification"]
    if reid:
        blocks += [Heading("Re-identification over the runs"),
                   Table("reidentification", ["matcher", *REID_FIGURES, "true pairs per run"],
                         [[matcher, *(_ratio_spread(figures[f]) for f in REID_FIGURES),
                           ", ".join(str(p) for p in figures["pairs_true"])] for matcher, figures in reid.items()])]
    return blocks


def arm_blocks(content: Mapping[str, Any], json_name: str) -> list[Block]:
    """The comparison with a second arm's runs (``--paired-with``): which run each is paired with and what tells
    them apart, then each method's difference between the arms."""
    paired = content.get("paired")
    if paired is None:
        return []
    pairs = Table("paired-runs", ["run", "source", "paired with", "differs in"],
                  [[str(i), run["source"], other["source"], ", ".join(other["differs_in"])]
                   for i, (run, other) in enumerate(zip(content["runs"], paired["runs"]))], labels=3)
    rows = []
    for entry in paired["differences"]:
        ap = entry["AP"]
        rows.append([entry["method"], dict(REGIONS_SHOWN)[entry["region"]],
                     *(_plus_minus(entry[c], c, signed=True) for c in COLUMNS), _interval(ap, "AP"),
                     f"{ap['better']} of {ap['n']}"])
    header = ["method", "region", *(f"{c} difference" for c in COLUMNS), "AP 95 % interval", "AP better in"]
    return [Heading("Against the paired runs"),
            Paragraph("Each run beside the run of the other arm on the same dataset and seed (`--paired-with`), and "
                      "the fingerprints that differ between them."),
            pairs,
            Paragraph("Each method in these runs minus the same method in the paired run, then mean ± sample standard "
                      "deviation over the worlds, the 95 % Student-t interval of the mean difference and the worlds "
                      "where these runs' AP was higher. A family `(best)` is at each arm's own best threshold. Each "
                      f"world's differences are in {json_name}."),
            Table("arm-differences", header, rows, labels=2)]


def _ratio_spread(stats: Mapping[str, Any]) -> str:
    if stats["mean"] is None:
        return "-"
    return format_ratio(stats["mean"]) + ("" if stats["sd"] is None else f" ± {format_ratio(stats['sd'])}")


# --------------------------------------------------------------------------- the command


def summarize(sources: Sequence[str], runs: Sequence[Mapping[str, Any]],
              paired: tuple[Sequence[str], Sequence[Mapping[str, Any]]] | None = None) -> dict[str, Any]:
    """report.json's content for ``runs`` read from ``sources``; ``paired``: the other arm's sources and runs,
    in the order of ``runs`` (:func:`read_paired_runs`)."""
    first = runs[0]
    return strict_json({
        "schema": RUNS_SCHEMA, "schema_version": SCHEMA_VERSION, "table_class": first["table_class"],
        "config": {name: first["config"][name] for name in SHARED_FIELDS},
        "runs": [{"source": source, "eval": run["eval"], **{name: run["config"][name] for name in RUN_IDENTITY},
                  "split_scenes": run["config"]["split_scenes"], "fingerprints": run["fingerprints"],
                  "gt": {region: figure(run, region, run["methods"][0], "gt") for region, _ in REGIONS_SHOWN},
                  "thresholds": run_thresholds(source)}
                 for source, run in zip(sources, runs)],
        "cells": table_cells(runs),
        "paired_differences": paired_differences(runs),
        "reidentification": reidentification(runs),
        "paired": None if paired is None else {
            "runs": [{"source": source, "eval": other["eval"], "fingerprints": other["fingerprints"],
                      "differs_in": sorted(name for name in run["fingerprints"]
                                           if run["fingerprints"][name] != other["fingerprints"].get(name))}
                     for source, other, run in zip(*paired, runs)],
            "differences": arm_differences(runs, paired[1])},
    })


def run(config: RunsReportConfig, out: str | Path, *, overwrite: bool = False,
        progress: Progress = SILENT) -> Report:
    """Read the runs, summarise them and write ``out`` atomically (module docstring).

    Raises:
        DataFormatError: a run is not a complete evaluation or a report.json.
        SianmsError: the runs were evaluated otherwise, or one is given twice.
        OutputExistsError: ``out`` may not be replaced (only a report folder, with ``overwrite``).
    """
    out = Path(out)
    check_output(out, overwrite)
    seen = snapshot(out)  # publishing refuses an out that changed meanwhile
    progress.start(2, "step", "report")
    runs = read_runs(config.evals)
    paired = read_paired_runs(config.evals, runs, config.paired_with) if config.paired_with else None
    content = summarize(config.evals, runs, paired)
    progress.advance()
    title = f"sianms report: {len(runs)} runs"
    published, markdown = build_folder(
        out, lambda staging: write_report_files(staging, title, document(content), content), seen)
    progress.advance()
    return Report(published, content, markdown)
