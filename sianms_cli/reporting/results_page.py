"""`sianms report RUN RUN ... --page PAGE.md`: a study's results page, and its JSON beside it.

The page (Markdown, for a repository's ``docs/results/``) is machine-made but for one section:

- a header: the command that makes the page, the commit of the sianms that ran it (``git
  rev-parse HEAD`` of its source tree, with a note of uncommitted changes; the package version
  where the source is not a git checkout), the machine (CPU model, cores) and the date;
- the runs, and where each run's thresholds came from (its calibration split and fingerprint,
  or its own split);
- the runs report's tables (:mod:`.runs_report`): Table I with its spread, the paired differences
  with their 95 % intervals, re-identification precision / recall / F1;
- what went wrong in the matches, duplicates left per region and the car AP per camera pair
  (where the evaluations have camera-pair regions), each as mean ± sd over the runs;
- the section **Analysis**, between two markers, which a person writes: a regeneration reads it
  back from the existing page and keeps it as it stands.

``PAGE`` with ``.json`` for ``.md`` holds the same figures (``"schema": "sianms-results-page"``):
the runs report's content, the header and the extra tables. Both files are written together
(neither or both). A ``PAGE`` that exists must be one this command wrote (its first line) with
both markers in place; anything else is refused, so no one's prose is overwritten.
"""

from __future__ import annotations

import json
import os
import platform
import shlex
import subprocess
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from sianms_cli import __version__
from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError, usable_cpus
from sianms_cli.io import make_folder, read_json, write_files_together
from sianms_cli.json_stream import is_finite_number
from sianms_cli.progress import SILENT, Progress
from sianms_cli.reporting.eval_table import REID_WRONG_COLUMNS, REID_WRONG_FIGURES, format_cell, pair_label
from sianms_cli.reporting.report import strict_json
from sianms_cli.reporting.report_html import Block, Heading, Paragraph, Table, render_markdown
from sianms_cli.reporting.runs_report import (
    RunsReportConfig,
    read_paired_runs,
    read_runs,
    result_blocks,
    spread,
    summarize,
)

SCHEMA = "sianms-results-page"
SCHEMA_VERSION = 1
FIRST_LINE = ("<!-- sianms-results-page: made by `sianms report --page`; everything but the section "
              "\"Analysis\" is rewritten when the page is made again -->")
ANALYSIS_BEGIN = ("<!-- analysis: begin. Written by a person; `sianms report --page` keeps what lies between "
                  "these two markers -->")
ANALYSIS_END = "<!-- analysis: end -->"
NEW_ANALYSIS = "*Not written yet: the study's author writes here what the tables show and what drives it.*"
GIT_TIMEOUT_S = 10


@dataclass(frozen=True)
class PageConfig:
    """The runs a page summarises, where it goes, and the command line that makes it (printed in its header)."""

    evals: tuple[str, ...]
    page: str
    command: str
    paired_with: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        RunsReportConfig(evals=self.evals, paired_with=self.paired_with)  # the same checks
        if not str(self.page).endswith(".md"):
            raise SianmsError(f"--page: a results page is Markdown: name a .md file, got '{self.page}'")
        object.__setattr__(self, "evals", tuple(str(source) for source in self.evals))
        object.__setattr__(self, "paired_with", tuple(str(source) for source in self.paired_with))
        object.__setattr__(self, "page", str(self.page))


@dataclass(frozen=True)
class Page:
    """What :func:`run` wrote: the page, its JSON, the JSON's content and the page's text."""

    page: Path
    json: Path
    content: dict[str, Any]
    markdown: str


def command_line(evals: Sequence[str], page: str, out: str | None = None, paired_with: Sequence[str] = ()) -> str:
    """The `sianms report` command that makes the page, quoted for a POSIX shell."""
    pairing = [word for source in paired_with for word in ("--paired-with", source)]
    return shlex.join(["sianms", "report", *evals, *pairing, "--page", page,
                       *(["--out", out] if out is not None else [])])


# --------------------------------------------------------------------------- the header


def source_commit(folder: Path | None = None) -> str | None:
    """``git rev-parse HEAD`` of the source tree holding the sianms package, "+ uncommitted changes" when its
    tracked files differ from it; None when the package is not the top of a git checkout (an installed wheel,
    even inside someone else's repository) or git is missing."""
    folder = (folder or Path(__file__).resolve().parents[2]).resolve()

    def git(*arguments: str) -> subprocess.CompletedProcess:
        return subprocess.run(["git", "-C", str(folder), *arguments], check=False, capture_output=True, text=True,
                              timeout=GIT_TIMEOUT_S)
    try:
        top = git("rev-parse", "--show-toplevel")
        if top.returncode != 0 or Path(top.stdout.strip()).resolve() != folder:
            return None
        head, status = git("rev-parse", "HEAD"), git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):
        return None
    if head.returncode != 0:
        return None
    return head.stdout.strip() + (" + uncommitted changes" if status.returncode == 0 and status.stdout.strip()
                                  else "")


def cpu_model(cpuinfo: str | None = None) -> str:
    """The CPU's model name (``/proc/cpuinfo``'s, else the platform's word for it)."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text(errors="replace")
        except OSError:
            cpuinfo = ""
    for line in cpuinfo.splitlines():
        key, _, value = line.partition(":")
        if key.strip() in ("model name", "Model", "cpu model") and value.strip():
            return value.strip()
    return platform.processor() or platform.machine() or "unknown"


def page_header(command: str) -> dict[str, Any]:
    """What the page's header states: command, commit, version, machine and date (UTC)."""
    return {"command": command, "commit": source_commit(), "sianms_version": __version__,
            "machine": {"cpu": cpu_model(), "cores": os.cpu_count(), "usable_cores": usable_cpus()},
            "date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")}


def header_blocks(header: Mapping[str, Any]) -> list[Block]:
    machine = header["machine"]
    commit = (f"`{header['commit']}` (sianms {header['sianms_version']})" if header["commit"]
              else f"sianms {header['sianms_version']} (not a git checkout)")
    return [Table("made-by", ["", ""], [
        ["command", f"`{header['command']}`"], ["commit", commit],
        ["machine", f"{machine['cpu']}, {machine['cores']} cores ({machine['usable_cores']} usable)"],
        ["date", header["date"]]], labels=2)]


# --------------------------------------------------------------------------- the extra tables


def _cell(run: Mapping[str, Any], region: str, method: str, source: str) -> float | None:
    """A run's car AP in ``region`` (a camera pair's), or None where it has none; a value no evaluation writes
    is named with the run's table.json."""
    cell = run["regions"].get(region, {}).get(method, {}).get(run["table_class"])
    value = cell.get("AP") if isinstance(cell, dict) else None
    if value is not None and not (is_finite_number(value) and 0 <= value <= 100):
        raise DataFormatError(Path(source) / "table.json" if Path(source).is_dir() else source,
                              "must be a number in [0, 100] or null", field=f"regions.{region}.{method}.AP")
    return value


def pair_regions(runs: Sequence[Mapping[str, Any]]) -> list[str]:
    """The camera-pair regions any run has, in the first run's order, then the others'."""
    regions: dict[str, None] = {}
    for run in runs:
        regions.update(dict.fromkeys(name for name in run["regions"] if name.startswith("overlap:")))
    return list(regions)


def pair_cells(sources: Sequence[str], runs: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """{pair region: {method: spread of car AP}} over the runs (None where a run has no such region)."""
    return {region: {method: spread([_cell(run, region, method, source) for source, run in zip(sources, runs)])
                     for method in runs[0]["methods"]}
            for region in pair_regions(runs)}


def duplicate_cells(runs: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """{region: {method: spread of the car duplicates left}} for All, Overlap and each camera pair."""
    name = runs[0]["table_class"]
    regions = ["all", "overlap", *pair_regions(runs)]
    return {region: {method: spread([run["duplicates"].get(method, {}).get(region, {}).get(name) for run in runs])
                     for method in runs[0]["methods"]}
            for region in regions}


def wrong_match_cells(runs: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """{matcher: {figure: spread}} of what went wrong in each matcher's pairs (counts per run)."""
    matchers = [m for m in runs[0]["reidentification"] if all(m in run["reidentification"] for run in runs)]
    return {matcher: {figure: spread([run["reidentification"][matcher].get(figure) for run in runs])
                      for figure in REID_WRONG_FIGURES}
            for matcher in matchers}


def _mean_sd(stats: Mapping[str, Any], digits: int) -> str:
    if stats["mean"] is None:
        return "-"
    mean = f"{stats['mean']:.{digits}f}"
    return mean if stats["sd"] is None else f"{mean} ± {stats['sd']:.{digits}f}"


def threshold_blocks(runs: Sequence[Mapping[str, Any]]) -> list[Block]:
    rows = []
    for i, run in enumerate(runs):
        used = run.get("thresholds")
        if used is None:
            rows.append([str(i), "-", "not recorded", "-", "-", "-", "-", "-"])
            continue
        calibration, own = used["calibration"], used.get("own_split")
        nms = ", ".join(choice["method"] for choice in used["nms"].values()) or "-"
        sources = sorted({choice["source"] for choice in used["nms"].values()}) or ["-"]
        rows.append([str(i), _threshold(used["dis_thr"]["value"]), used["dis_thr"]["source"], nms,
                     ", ".join(sources), "-" if calibration is None
                     else f"{calibration['split']} `{calibration['sha256'][:12]}` ({calibration['path']})",
                     "-" if own is None else _threshold(own["dis_thr"]),
                     "-" if own is None else ", ".join(own["nms"].values()) or "-"])
    return [Heading("Thresholds"),
            Paragraph("Where each run's siaNMS distance threshold (dis_thr: siaNMS, hybrid, gated siaNMS) and each "
                      "NMS family's reported threshold came from: *calibration* is `sianms eval --thresholds-from`, "
                      "a split of other scenes (named with the first 12 characters of its thresholds.json's SHA-256 "
                      "and its folder); *this split* means chosen on the split the run reports. The last two columns "
                      "are what the reported split's own labels choose (its thresholds.json), shown for comparison "
                      "and used by no table. The hybrid's NMS is the paper's IoU 0.3 throughout."),
            Table("thresholds", ["run", "dis_thr", "dis_thr from", "NMS reported as best", "NMS from",
                                 "calibration split", "dis_thr this split chooses", "NMS this split chooses"],
                  rows, labels=1)]


def _threshold(value: float | None) -> str:
    return "-" if value is None else f"{value:.4g}"


def extra_blocks(content: Mapping[str, Any]) -> list[Block]:
    """What went wrong in the matches, duplicates left and car AP per camera pair, over the runs."""
    blocks: list[Block] = []
    wrong = content["wrong_matches"]
    if wrong:
        blocks += [Heading("What went wrong in the matches"),
                   Paragraph("Per run, mean ± sample standard deviation of the counts (see the evaluation's table.md "
                             "for what each column counts)."),
                   Table("wrong-matches", ["matcher", *REID_WRONG_COLUMNS],
                         [[matcher, *(_mean_sd(figures[f], 1) for f in REID_WRONG_FIGURES)]
                          for matcher, figures in wrong.items()])]
    name = content["table_class"]
    regions = list(content["duplicates"])
    labels = {"all": "All", "overlap": "Overlap"}
    methods = list(next(iter(content["duplicates"].values()), {}))
    blocks += [Heading(f"Duplicates left ({name})"),
               Paragraph(f"False positives at 2 m with a ground-truth {name} within 2 m that another prediction took, "
                         "per region (camera pairs by their overlap): mean ± sample standard deviation over the runs."),
               Table("duplicates", ["method", *(labels.get(r) or pair_label(r) for r in regions)],
                     [[method, *(_mean_sd(content["duplicates"][r][method], 1) for r in regions)]
                      for method in methods])]
    pairs = content["pairs"]
    if pairs:
        blocks += [Heading(f"AP per camera pair ({name})"),
                   Paragraph(f"{name} AP (%) in each contiguous camera pair's overlap: mean ± sample standard "
                             "deviation over the runs with ground truth there (n shown where some have none)."),
                   Table("camera-pairs", ["method", *(pair_label(r) for r in pairs)],
                         [[method, *(_pair_cell(pairs[r][method], len(content["runs_report"]["runs"]))
                                     for r in pairs)]
                          for method in next(iter(pairs.values()))])]
    return blocks


def _pair_cell(stats: Mapping[str, Any], runs: int) -> str:
    text = "-" if stats["mean"] is None else (format_cell(stats["mean"], "AP") if stats["sd"] is None
                                             else f"{format_cell(stats['mean'], 'AP')} ± {stats['sd']:.1f}")
    return text if stats["n"] in (0, runs) else f"{text} (n = {stats['n']})"


# --------------------------------------------------------------------------- the page


def read_analysis(page: Path) -> str | None:
    """The Analysis section's text of an existing page (None for a new page).

    Raises:
        OutputExistsError: ``page`` is a folder, or a file this command did not write.
        DataFormatError: the markers around the section are missing or out of order.
    """
    if not page.exists() and not page.is_symlink():
        return None
    if not page.is_file():
        raise OutputExistsError(f"--page: {page} is not a file; choose another --page")
    text = page.read_text(encoding="utf-8", errors="replace")
    if not text.startswith(FIRST_LINE.split(";")[0]):
        raise OutputExistsError(f"--page: {page} exists and is not a page `sianms report --page` wrote; "
                                "choose another --page")
    begin, end = text.find(ANALYSIS_BEGIN), text.find(ANALYSIS_END)
    if begin < 0 or end < begin:
        raise DataFormatError(page, "the markers of the section Analysis are missing or out of order, so its text "
                                    f"cannot be kept; put back the lines '{ANALYSIS_BEGIN}' and '{ANALYSIS_END}' "
                                    "around it", field="Analysis")
    return text[begin + len(ANALYSIS_BEGIN):end].strip("\n")


def check_json_beside(path: Path) -> None:
    """Refuse a JSON file beside the page that another tool wrote."""
    if not path.exists() and not path.is_symlink():
        return
    if not path.is_file():
        raise OutputExistsError(f"--page: {path} is not a file; choose another --page")
    try:
        content = read_json(path)
    except DataFormatError:
        content = None
    if not isinstance(content, dict) or content.get("schema") != SCHEMA:
        raise OutputExistsError(f"--page: {path} exists and is not the JSON of a page `sianms report --page` wrote; "
                                "choose another --page")


def check_page_outputs(page: Path) -> str | None:
    """Refuse a page or a JSON beside it that this command did not write (before anything is written);
    the existing page's Analysis text, or None for a new page."""
    analysis = read_analysis(page)
    check_json_beside(page.with_suffix(".json"))
    return analysis


def page_markdown(content: Mapping[str, Any], analysis: str) -> str:
    """The page: the machine-made blocks, then the Analysis section with ``analysis`` between its markers."""
    runs_report = content["runs_report"]
    runs = runs_report["runs"]
    blocks: list[Block] = [
        Paragraph(f"Machine-made by `sianms report --page` from {len(runs)} runs: every table below comes from the "
                  "command in the header and changes only when it is run again. The section Analysis is written by "
                  "hand and kept when the page is made again."),
        *header_blocks(content["header"]),
        Heading("Runs"),
        Table("runs", ["run", "source", "seed", "dataset", "scenes", "GT cars, all", "GT cars, overlap"],
              [[str(i), run["source"], str(run["seed"]), run["dataset_sha256"][:12], str(len(run["split_scenes"])),
                str(run["gt"]["all"]), str(run["gt"]["overlap"])] for i, run in enumerate(runs)], labels=2),
        *threshold_blocks(runs),
        *result_blocks(runs_report, content["json_name"]),
        *extra_blocks(content),
        Heading("Analysis"),
    ]
    body = render_markdown(content["title"], blocks).rstrip("\n")
    return f"{FIRST_LINE}\n{body}\n\n{ANALYSIS_BEGIN}\n{analysis}\n{ANALYSIS_END}\n"


def page_content(sources: Sequence[str], runs: Sequence[Mapping[str, Any]], title: str, json_name: str,
                 header: Mapping[str, Any],
                 paired: tuple[Sequence[str], Sequence[Mapping[str, Any]]] | None = None) -> dict[str, Any]:
    """The JSON beside the page: the runs report's content (with the second arm's comparison where ``paired``),
    the header and the page's extra tables."""
    runs_report = summarize(sources, runs, paired)
    return strict_json({"schema": SCHEMA, "schema_version": SCHEMA_VERSION, "title": title, "json_name": json_name,
                        "header": dict(header),
                        "runs_report": runs_report, "table_class": runs_report["table_class"],
                        "wrong_matches": wrong_match_cells(runs), "duplicates": duplicate_cells(runs),
                        "pairs": pair_cells(sources, runs)})


def run(config: PageConfig, *, progress: Progress = SILENT, header: Mapping[str, Any] | None = None) -> Page:
    """Read the runs and write the page and its JSON together (module docstring).

    Args:
        config: the runs, the page and the command line.
        header: the header's facts (:func:`page_header` of the command when None).

    Raises:
        DataFormatError: a run is not a complete evaluation or a report.json; the existing page lost its markers.
        SianmsError: the runs were evaluated otherwise, or one is given twice.
        OutputExistsError: the page or its JSON exists and is not this command's.
    """
    page = Path(config.page)
    json_path = page.with_suffix(".json")
    analysis = check_page_outputs(page)
    progress.start(2, "step", "page")
    runs = read_runs(config.evals)
    paired = read_paired_runs(config.evals, runs, config.paired_with) if config.paired_with else None
    content = page_content(config.evals, runs, f"{page.stem}: {len(runs)} runs", json_path.name,
                           header if header is not None else page_header(config.command), paired)
    progress.advance()
    markdown = page_markdown(content, NEW_ANALYSIS if analysis is None else analysis)
    make_folder(page.parent)
    write_files_together({page: markdown, json_path: json.dumps(content, indent=2, allow_nan=False) + "\n"},
                         overwrite=True)
    progress.advance()
    return Page(page, json_path, content, markdown)
