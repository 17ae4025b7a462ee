"""`sianms report` through the CLI: the table, --json, the gate's exit codes, one-line errors, start-up."""

from __future__ import annotations

import json
import shutil

import pytest
from typer.testing import CliRunner

from sianms_cli.cli import app
from sianms_cli.cli.report import DEFAULT_ALLOWANCES_TEXT
from sianms_cli.reporting.report import allowances_text

runner = CliRunner()




def invoke(*arguments: str):
    return runner.invoke(app, ["report", *arguments, "--quiet"])


@pytest.fixture
def folders(eval_folders):
    return eval_folders


@pytest.fixture
def runs(tmp_path, folders):
    evaluation = folders.make_eval(tmp_path / "eval")
    return evaluation, shutil.copytree(evaluation, tmp_path / "baseline")


def test_prints_the_tables_and_the_html_path(runs):
    evaluation, _ = runs
    result = invoke(str(evaluation))
    assert result.exit_code == 0, result.output
    assert "| All | vanilla | 31.2 | 0.612 | 24.6 | 1.381 | 45.5 |" in result.stdout
    assert result.stdout.rstrip().endswith(f"wrote {evaluation / 'report' / 'report.html'}")


def test_json_is_all_there_is_on_stdout(runs, tmp_path):
    evaluation, baseline = runs
    result = invoke(str(evaluation), "--baseline", str(baseline), "--out", str(tmp_path / "r"), "--json")
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout) == json.loads((tmp_path / "r" / "report.json").read_text())
    assert result.stdout == (tmp_path / "r" / "report.json").read_text()


def test_the_gate_exits_1_listing_exactly_the_regressed_cells(runs, folders):
    evaluation, baseline = runs
    folders.edit_table(evaluation, lambda t: t["regions"]["overlap"]["sianms"]["car"].update(AP=25.0))
    result = invoke(str(evaluation), "--baseline", str(baseline))
    assert result.exit_code == 1, result.output
    assert result.stderr.splitlines() == [
        "1 cell(s) regressed beyond the allowances:",
        "  overlap sianms AP: baseline 25.7, now 25.0, allowance 0.5 (dropped by 0.6797)"]
    assert "| overlap | sianms | AP | 25.7 | 25.0 | 0.5 | dropped by 0.6797 |" in result.stdout
    result = invoke(str(evaluation), "--baseline", str(baseline), "--max-drop", "ap=0.7", "--overwrite")
    assert result.exit_code == 0, result.output
    result = invoke(str(evaluation), "--baseline", str(evaluation / "report" / "report.json"), "--json",
                    "--out", str(evaluation / "again"))
    assert result.exit_code == 0 and json.loads(result.stdout)["regressions"] == []


@pytest.mark.parametrize(("arguments", "message"), [
    (["--max-drop", "ap=1,bogus=2"], "error: --max-drop: unknown key 'bogus'"),
    (["--max-drop", "ap=-1"], "error: --max-drop: ap=-1: must be a number >= 0"),
    (["--baseline", "{other}"], "error: --baseline: {other} was evaluated with another config (differs in: "
                                "split_scenes); pass --force"),
    (["--baseline", "{missing}"], "error: {missing}: file not found"),
])
def test_bad_input_is_one_error_line_and_exit_2(runs, folders, tmp_path, arguments, message):
    evaluation, _ = runs
    other = folders.make_eval(tmp_path / "other", split_scenes=["scene-0103"])
    names = {"other": str(other), "missing": str(tmp_path / "missing.json")}
    result = invoke(str(evaluation), *(argument.format(**names) for argument in arguments))
    assert result.exit_code == 2, result.output
    assert result.output.startswith(message.format(**names))
    assert len(result.output.strip().splitlines()) == 1 and "Traceback" not in result.output


def test_force_compares_runs_of_another_config(runs, folders, tmp_path):
    evaluation, _ = runs
    other = folders.make_eval(tmp_path / "other", split_scenes=["scene-0103"])
    result = invoke(str(evaluation), "--baseline", str(other), "--force")
    assert result.exit_code == 0, result.output
    assert "although the configs differ in: split_scenes" in result.stdout


def test_an_incomplete_evaluation_exits_2_naming_file_and_field(runs):
    evaluation, _ = runs
    marker = json.loads((evaluation / "eval.json").read_text())
    (evaluation / "eval.json").write_text(json.dumps({**marker, "complete": False}))
    result = invoke(str(evaluation))
    assert result.exit_code == 2
    assert result.output.startswith(f"error: {evaluation / 'eval.json'}: field 'complete': the evaluation is not "
                                    "complete")


def test_help_states_the_default_allowances():
    assert DEFAULT_ALLOWANCES_TEXT == allowances_text()
    result = runner.invoke(app, ["report", "-h"])
    assert result.exit_code == 0 and DEFAULT_ALLOWANCES_TEXT in result.output.replace("\n", "").replace(" ", "")
