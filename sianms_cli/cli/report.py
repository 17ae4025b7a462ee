"""`sianms report`: an evaluation's Table I as Markdown, HTML and JSON; with --baseline, a regression gate;
of several evaluations (seeds), Table I over them with its spread and the paired differences, as a report
folder (--out) or a study's results page (--page)."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from sianms_cli.cli._app import ProgressBar, command

# Kept here as text so that `-h` imports no library code; a test checks it equals the library's defaults.
DEFAULT_ALLOWANCES_TEXT = "ap=0.5,ate=0.02,ase=0.5,aoe=0.02,reid=0.05"


@command("report")
def report_cli(
    evals: List[Path] = typer.Argument(..., metavar="EVAL", help="A complete `sianms eval` output folder; "
                                                                    "several (or their report.json): a report over "
                                                                    "runs, which needs --out."),
    baseline: Optional[Path] = typer.Option(None, help="Compare with this evaluation folder or report.json (a "
                                                       "report.json is what a repository commits for CI)."),
    max_drop: Optional[str] = typer.Option(None, help="Allowances over the defaults "
                                                      f"{DEFAULT_ALLOWANCES_TEXT}: AP drop in points, ATE rise in m, "
                                                      "ASE rise in points, AOE rise in rad, re-identification "
                                                      "precision/recall/F1 drop as a fraction."),
    force: bool = typer.Option(False, "--force", help="Compare even when the runs' comparable configs differ."),
    out: Optional[Path] = typer.Option(None, help="Report folder to write [default: EVAL/report]."),
    page: Optional[Path] = typer.Option(None, help="Several EVALs: write this results page (Markdown, e.g. "
                                                   "docs/results/NAME.md) and NAME.json beside it; its section "
                                                   "Analysis is kept when the page is made again."),
    paired_with: Optional[List[Path]] = typer.Option(
        None, help="Several EVALs: a run of a second arm on one EVAL's world (the same dataset and seed), given once "
                   "per EVAL; each method is compared between the arms, world by world."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing report folder."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    as_json: bool = typer.Option(False, "--json", help="Print report.json; nothing else goes to stdout."),
) -> None:
    """Table I of an evaluation with the paper's numbers beside, re-identification, duplicates, timings and
    curves, written as report.md, a self-contained report.html and report.json.

    With --baseline, every Table I cell and re-identification figure is compared: exit code 1 when any
    regresses beyond its allowance (listed), 0 otherwise, 2 on bad input or differing configs.

    Given several evaluations (seeds of one study), Table I over them as mean ± standard deviation and
    the merging methods' paired differences from vanilla and Axis-NMS with a 95 % interval, into --out; with
    --page, the study's results page (those tables, duplicates left and camera pairs, headed by the command,
    commit, machine and date) and its JSON. With --paired-with, the runs of a second arm on the same worlds
    (another detector, say): every method's difference between the arms, world by world, with its interval.
    """
    import json

    paired = tuple(paired_with or ())
    if page is not None:
        _results_page(evals, paired, page, baseline, max_drop, force, out, overwrite, quiet, as_json)
        return
    if len(evals) > 1:
        report = _runs_report(evals, paired, baseline, max_drop, force, out, overwrite, quiet)
    else:
        if paired:
            from sianms_cli.errors import SianmsError

            raise SianmsError("--paired-with: arms are compared over several runs; give at least two EVAL")
        from sianms_cli.reporting.report import ReportConfig, run

        config = ReportConfig(eval=str(evals[0]), baseline=None if baseline is None else str(baseline),
                              max_drop=max_drop, force=force)
        with ProgressBar(quiet) as bar:
            report = run(config, out, overwrite=overwrite, progress=bar)
    if as_json:
        typer.echo(json.dumps(report.content, indent=2, allow_nan=False))
    else:
        typer.echo(report.markdown)
        typer.echo(f"wrote {report.html}")
    if report.regressions:
        from sianms_cli.reporting.report import regression_lines

        typer.echo(f"{len(report.regressions)} cell(s) regressed beyond the allowances:", err=True)
        for line in regression_lines(report.regressions):
            typer.echo(f"  {line}", err=True)
        raise typer.Exit(1)


def _refuse_gate_flags(baseline: Optional[Path], max_drop: Optional[str], force: bool) -> None:
    from sianms_cli.errors import SianmsError

    for flag, given in (("--baseline", baseline is not None), ("--max-drop", max_drop is not None),
                        ("--force", force)):
        if given:
            raise SianmsError(f"{flag}: the gate compares one evaluation with its baseline; give one EVAL")


def _results_page(evals: List[Path], paired: tuple[Path, ...], page: Path, baseline: Optional[Path],
                  max_drop: Optional[str], force: bool, out: Optional[Path], overwrite: bool, quiet: bool,
                  as_json: bool) -> None:
    import json

    from sianms_cli.errors import SianmsError
    from sianms_cli.reporting.results_page import PageConfig, check_page_outputs, command_line, run

    _refuse_gate_flags(baseline, max_drop, force)
    if len(evals) < 2:
        raise SianmsError("--page: a results page summarises several runs; give at least two EVAL")
    sources = [str(folder) for folder in evals]
    paired_sources = tuple(str(folder) for folder in paired)
    config = PageConfig(evals=tuple(sources), page=str(page), paired_with=paired_sources,
                        command=command_line(sources, str(page), None if out is None else str(out), paired_sources))
    if out is not None:
        check_page_outputs(page)  # before the report folder is written
        report = _runs_report(evals, paired, None, None, False, out, overwrite, quiet)
    with ProgressBar(quiet) as bar:
        written = run(config, progress=bar)
    if as_json:
        typer.echo(json.dumps(written.content, indent=2, allow_nan=False))
        return
    typer.echo(f"wrote {written.page} and {written.json}")
    if out is not None:
        typer.echo(f"wrote {report.html}")


def _runs_report(evals: List[Path], paired: tuple[Path, ...], baseline: Optional[Path], max_drop: Optional[str],
                 force: bool, out: Optional[Path], overwrite: bool, quiet: bool):
    from sianms_cli.errors import SianmsError
    from sianms_cli.reporting.runs_report import RunsReportConfig, run

    _refuse_gate_flags(baseline, max_drop, force)
    if out is None:
        raise SianmsError("--out: a report over several runs has no EVAL folder of its own; name its folder")
    config = RunsReportConfig(evals=tuple(str(folder) for folder in evals),
                              paired_with=tuple(str(folder) for folder in paired))
    with ProgressBar(quiet) as bar:
        return run(config, out, overwrite=overwrite, progress=bar)
