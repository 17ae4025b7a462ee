"""`sianms report RUN RUN --page PAGE.md`: a study's results page from two tiny runs, and its Analysis kept."""

from __future__ import annotations

import json

import numpy as np
import pytest
from report_helpers import PAIR, cell, edit_table, make_eval
from typer.testing import CliRunner

from sianms_cli.cli import app
from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError
from sianms_cli.reporting.results_page import (
    ANALYSIS_BEGIN,
    ANALYSIS_END,
    FIRST_LINE,
    NEW_ANALYSIS,
    PageConfig,
    cpu_model,
    run,
    source_commit,
)

METHODS = ("vanilla", "axis-nms", "axis-nms@0.1", "sianms", "oracle")
HEADER = {"command": "sianms report a b --page docs/results/study.md", "commit": "0123abc", "sianms_version": "9.9",
          "machine": {"cpu": "Test CPU 3000", "cores": 4, "usable_cores": 2}, "date": "2030-01-02 03:04 UTC"}
CALIBRATION = {"path": "/studies/s1/eval-calib", "split": "calib", "split_scenes": ["scene-0001"], "sha256": "ab" * 32}
SIANMS_SHIFT = (2.0, -1.0)  # added to siaNMS's car AP in both regions, run k
DUPLICATES_SHIFT = (0, 4)  # added to every duplicates count of run k


def make_run(tmp_path, k):
    """Run k of two: its own dataset and seed; run 1 took its thresholds from a calibration split."""
    folder = make_eval(tmp_path / f"run{k}", methods=METHODS, seed=k, dataset_sha256=f"{k}" * 64)

    def change(table):
        for region in ("all", "overlap"):
            table["regions"][region]["sianms"]["car"]["AP"] += SIANMS_SHIFT[k]
        for by_region in table["duplicates"].values():
            for counts in by_region.values():
                counts["car"] += DUPLICATES_SHIFT[k]
        table["best_nms"] = {"axis-nms": "axis-nms@0.1"}
        if k == 1:
            (folder / "thresholds.json").write_text(json.dumps({"dis_thr": {"value": 0.6543},
                                                                "nms": {"axis-nms": {"method": "axis-nms"}}}))
            table["thresholds"] = {"dis_thr": {"value": 0.8123, "source": "calibration"},
                                   "nms": {"axis-nms": {"method": "axis-nms@0.1", "iou": 0.1, "source": "calibration"}},
                                   "hybrid_nms_iou": 0.3, "calibration": CALIBRATION}
    edit_table(folder, change)
    return folder


@pytest.fixture
def runs(tmp_path):
    return [make_run(tmp_path, k) for k in range(2)]


def make_page(runs, page, header=HEADER):
    return run(PageConfig(evals=tuple(map(str, runs)), page=str(page), command=header["command"]), header=header)


def rows_of(markdown, first_cell):
    """The cells of the Markdown table rows that start with ``first_cell``."""
    return [[c.strip() for c in line.strip("|").split("|")] for line in markdown.splitlines()
            if line.startswith(f"| {first_cell} |")]


def test_the_page_is_headed_by_command_commit_machine_and_date_and_holds_every_table(runs, tmp_path):
    page = make_page(runs, tmp_path / "docs" / "results" / "study.md")
    text = page.page.read_text()
    assert text == page.markdown and text.splitlines()[0] == FIRST_LINE
    assert "# study: 2 runs" in text
    assert rows_of(text, "command") == [["command", f"`{HEADER['command']}`"]]
    assert rows_of(text, "commit") == [["commit", "`0123abc` (sianms 9.9)"]]
    assert rows_of(text, "machine") == [["machine", "Test CPU 3000, 4 cores (2 usable)"]]
    assert rows_of(text, "date") == [["date", "2030-01-02 03:04 UTC"]]
    headings = [line for line in text.splitlines() if line.startswith("## ")]
    assert headings == ["## Runs", "## Thresholds", "## Table I over the runs (car)", "## Paired differences",
                        "## Re-identification over the runs", "## What went wrong in the matches",
                        "## Duplicates left (car)", "## AP per camera pair (car)", "## Analysis"]
    assert text.endswith(f"## Analysis\n\n{ANALYSIS_BEGIN}\n{NEW_ANALYSIS}\n{ANALYSIS_END}\n")
    assert json.loads(page.json.read_text()) == page.content and page.json == tmp_path / "docs" / "results" / \
        "study.json"


def test_the_tables_hold_the_runs_figures(runs, tmp_path):
    text = make_page(runs, tmp_path / "study.md").markdown
    # paired difference, overlap: siaNMS (method 3) - vanilla (method 0), shifted by +2 and -1
    differences = [cell(3, 1, "car")["AP"] - cell(0, 1, "car")["AP"] + shift for shift in SIANMS_SHIFT]
    row = next(r for r in rows_of(text, "sianms − vanilla") if r[1] == "Overlap")
    assert row[2] == f"{np.mean(differences):+.1f} ± {np.std(differences, ddof=1):.1f}" and row[-1] == "2 of 2"
    # duplicates left: report_helpers writes 27 - 5 * method - region; run 1 adds 4
    duplicates = rows_of(text, "sianms")[-2]  # the duplicates table, then the camera-pair table
    assert duplicates[1:] == [f"{12 + 2:.1f} ± {np.std([12, 16], ddof=1):.1f}",
                              f"{11 + 2:.1f} ± {np.std([11, 15], ddof=1):.1f}",
                              f"{10 + 2:.1f} ± {np.std([10, 14], ddof=1):.1f}"]
    pair_header = next(line for line in text.splitlines() if line.startswith("| method |") and "FRONT_RIGHT" in line
                       and "Overlap" not in line)
    assert pair_header == "| method | FRONT / FRONT_RIGHT |"
    assert rows_of(text, "oracle")[-1] == ["oracle", f"{cell(4, 2, 'car')['AP']:.1f} ± 0.0"]
    wrong = rows_of(text, "gated-sianms")[-1]
    assert wrong[1:3] == ["3.0 ± 0.0", "1.0 ± 0.0"]  # no true partner, partner passed over


def test_each_runs_thresholds_are_named_with_their_source(runs, tmp_path):
    page = make_page(runs, tmp_path / "study.md")
    rows = rows_of(page.markdown, "0") + rows_of(page.markdown, "1")
    thresholds = [row for row in rows if len(row) == 8]
    assert thresholds[0] == ["0", "-", "not recorded", "-", "-", "-", "-", "-"]
    assert thresholds[1] == ["1", "0.8123", "calibration", "axis-nms@0.1", "calibration",
                             f"calib `{'ab' * 6}` (/studies/s1/eval-calib)", "0.6543", "axis-nms"]
    assert page.content["runs_report"]["runs"][1]["thresholds"]["calibration"] == {
        key: CALIBRATION[key] for key in ("path", "split", "sha256")}
    assert "on a calibration split for the runs that took their thresholds from one" in page.markdown
    assert "the intervals of the error columns, are in study.json." in page.markdown


def test_making_the_page_again_keeps_the_analysis_and_renews_the_tables(runs, tmp_path):
    path = tmp_path / "study.md"
    first = make_page(runs, path)
    analysis = ("siaNMS trails Axis-NMS by **1.0** AP here.\n\n| seed | note |\n|---|---|\n| 0 | a wrong match |\n"
                "<!-- a comment of the author's -->")
    path.write_text(first.markdown.replace(NEW_ANALYSIS, analysis))
    edit_table(runs[0], lambda t: t["regions"]["overlap"]["sianms"]["car"].update(AP=50.0))
    again = make_page(runs, path, {**HEADER, "date": "2031-01-01 00:00 UTC"})
    text = path.read_text()
    assert text.endswith(f"{ANALYSIS_BEGIN}\n{analysis}\n{ANALYSIS_END}\n")
    assert "2031-01-01 00:00 UTC" in text and "2030-01-02" not in text
    assert again.content["runs_report"]["cells"]["overlap"]["sianms"]["AP"]["values"][0] == 50.0
    assert make_page(runs, path).markdown.count(analysis) == 1  # a third time: still once


def test_a_page_or_json_someone_else_wrote_is_refused_and_left_alone(runs, tmp_path):
    mine = tmp_path / "mine.md"
    mine.write_text("# My notes\n")
    with pytest.raises(OutputExistsError, match="is not a page `sianms report --page` wrote"):
        make_page(runs, mine)
    assert mine.read_text() == "# My notes\n" and not (tmp_path / "mine.json").exists()
    page = make_page(runs, tmp_path / "study.md")
    page.page.write_text(page.markdown.replace(ANALYSIS_END, ""))
    with pytest.raises(DataFormatError, match="field 'Analysis': the markers of the section Analysis are missing"):
        make_page(runs, page.page)
    (tmp_path / "other.json").write_text('{"schema": "something else"}')
    with pytest.raises(OutputExistsError, match="other.json exists and is not the JSON of a page"):
        make_page(runs, tmp_path / "other.md")
    assert not (tmp_path / "other.md").exists()
    with pytest.raises(SianmsError, match="--page: a results page is Markdown"):
        PageConfig(evals=tuple(map(str, runs)), page=str(tmp_path / "study.html"), command="x")


def test_the_cli_writes_the_page_with_its_command_and_refuses_one_run(runs, tmp_path):
    page = tmp_path / "study.md"
    cli = CliRunner()
    result = cli.invoke(app, ["report", *map(str, runs), "--page", str(page), "--quiet"])
    assert result.exit_code == 0, result.output
    assert result.output == f"wrote {page} and {tmp_path / 'study.json'}\n"
    header = json.loads((tmp_path / "study.json").read_text())["header"]
    assert header["command"] == f"sianms report {runs[0]} {runs[1]} --page {page}"
    assert header["commit"] == source_commit() and header["machine"]["cores"] >= 1
    result = cli.invoke(app, ["report", str(runs[0]), "--page", str(page), "--quiet"])
    assert result.exit_code == 2 and result.output.startswith("error: --page: a results page summarises several runs")
    result = cli.invoke(app, ["report", *map(str, runs), "--page", str(page), "--baseline", str(runs[0]), "--quiet"])
    assert result.exit_code == 2 and result.output.startswith("error: --baseline: the gate compares one")


def test_a_pair_figure_no_evaluation_writes_is_named(runs, tmp_path):
    edit_table(runs[1], lambda t: t["regions"][PAIR]["sianms"]["car"].update(AP="high"))
    with pytest.raises(DataFormatError, match=rf"run1/table.json: field 'regions.{PAIR}.sianms.AP'"):
        make_page(runs, tmp_path / "study.md")


@pytest.mark.parametrize(("thresholds", "field"), [
    ({"dis_thr": {"value": "0.8", "source": "calibration"}, "nms": {}, "calibration": None}, "thresholds.dis_thr"),
    ({"dis_thr": {"value": 0.8, "source": "x"}, "nms": {"axis-nms": "axis-nms@0.1"}, "calibration": None},
     "thresholds.nms"),
    ({"dis_thr": {"value": 0.8, "source": "x"}, "nms": {}, "calibration": {"path": "/c"}}, "thresholds.calibration"),
])
def test_an_edited_thresholds_record_is_named_by_field(runs, tmp_path, thresholds, field):
    edit_table(runs[1], lambda t: t.update(thresholds=thresholds))
    with pytest.raises(DataFormatError, match=rf"run1/table.json: field '{field}'"):
        make_page(runs, tmp_path / "study.md")


def test_an_edited_thresholds_file_of_a_run_is_named_by_field(runs, tmp_path):
    (runs[1] / "thresholds.json").write_text(json.dumps({"dis_thr": {"value": "low"}, "nms": {}}))
    with pytest.raises(DataFormatError, match="run1/thresholds.json: field 'dis_thr'"):
        make_page(runs, tmp_path / "study.md")


def test_commit_and_cpu_model_where_there_is_no_checkout_or_proc(tmp_path):
    assert source_commit(tmp_path) is None
    assert cpu_model("processor\t: 0\nvendor_id\t: X\nmodel name\t: Fast CPU 9\n") == "Fast CPU 9"
    assert cpu_model("") != ""


def test_a_page_of_a_second_arm_holds_the_comparison_and_its_command(runs, tmp_path):
    arm = [make_eval(tmp_path / f"arm{k}", methods=METHODS, seed=k, dataset_sha256=f"{k}" * 64,
                     siamese_sha256="t" * 64) for k in range(2)]
    page = tmp_path / "arm.md"
    pairing = [word for folder in runs for word in ("--paired-with", str(folder))]
    result = CliRunner().invoke(app, ["report", *map(str, arm), *pairing, "--page", str(page), "--out",
                                      str(tmp_path / "report"), "--quiet"])
    assert result.exit_code == 0, result.output
    content = json.loads((tmp_path / "arm.json").read_text())
    assert content["header"]["command"] == (f"sianms report {arm[0]} {arm[1]} --paired-with {runs[0]} --paired-with "
                                            f"{runs[1]} --page {page} --out {tmp_path / 'report'}")
    markdown = page.read_text()
    assert "## Against the paired runs" in markdown
    arm_row, = (row for row in rows_of(markdown, "sianms") if row[1] == "All")
    assert arm_row[2] == "-0.5 ± 2.1" and arm_row[-1] == "1 of 2"  # the first arm's +2 and -1 taken away
    differences = next(e for e in content["runs_report"]["paired"]["differences"]
                       if (e["method"], e["region"]) == ("sianms", "all"))
    assert differences["AP"]["values"] == pytest.approx([-s for s in SIANMS_SHIFT])
    assert [r["differs_in"] for r in content["runs_report"]["paired"]["runs"]] == [["siamese_sha256"]] * 2
    assert json.loads((tmp_path / "report" / "report.json").read_text())["paired"] == content["runs_report"]["paired"]
