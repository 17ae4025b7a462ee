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


def _tree(folder):
    return {str(path.relative_to(folder)): path.read_bytes() if path.is_file() else None
            for path in sorted(folder.rglob("*"))}


@pytest.mark.parametrize("holder", ["report folder", "copied report.json"])
@pytest.mark.parametrize(("foreign", "make"), [
    ("notes.txt", lambda path: path.write_text("precious")),
    ("photos", lambda path: (path.mkdir(), (path / "a.jpg").write_text("x"))),
])
def test_a_folder_with_entries_no_report_writes_is_left_intact(runs, tmp_path, holder, foreign, make):
    evaluation, _ = runs
    assert invoke(str(evaluation)).exit_code == 0
    out = evaluation / "report"
    if holder == "copied report.json":
        out = tmp_path / "mine"
        out.mkdir()
        shutil.copy(evaluation / "report" / "report.json", out)
    make(out / foreign)
    before = _tree(out)
    for flags in (["--overwrite"], []):
        result = invoke(str(evaluation), "--out", str(out), *flags)
        assert result.exit_code == 2, result.output
        assert result.output.splitlines() == [f"error: {out}: not replaced: '{foreign}' is not something sianms report "
                                              "writes; remove it yourself or choose another --out"]
        assert _tree(out) == before


def test_overwrite_replaces_a_report_folder(runs):
    evaluation, _ = runs
    assert invoke(str(evaluation)).exit_code == 0
    (evaluation / "report" / "report.md").write_text("an older report")
    result = invoke(str(evaluation), "--overwrite")
    assert result.exit_code == 0, result.output
    names = sorted(path.name for path in (evaluation / "report").iterdir())
    assert names == ["report.html", "report.json", "report.md"]
    assert (evaluation / "report" / "report.md").read_text() != "an older report"


def _set(*keys, value):
    def change(table):
        for key in keys[:-1]:
            table = table[key]
        table[keys[-1]] = value
    return change


@pytest.mark.parametrize(("change", "message"), [
    (_set("duplicates", value=5), "field 'duplicates': must be an object, got int"),
    (_set("duplicates", "vanilla", value=5), "field 'duplicates.vanilla': must be an object, got int"),
    (_set("duplicates", "sianms", "overlap", "car", value="x"),
     "field 'duplicates.sianms.overlap.car': must be a whole number >= 0"),
    (_set("best_nms", value=3), "field 'best_nms': must be an object, got int"),
    (_set("best_nms", "axis-nms", value="axis-nms@0.7"),
     "field 'best_nms.axis-nms': must be one of the methods, got 'axis-nms@0.7'"),
    (_set("regions", "all", "vanilla", "car", "AP", value=float("nan")),
     "field 'regions.all.vanilla.car.AP': must be a number in [0, 100] or null"),
    (_set("boxes", value="x"), "field 'boxes': must be an object, got str"),
    (_set("boxes", "oracle", value=-1), "field 'boxes.oracle': must be a whole number >= 0"),
    (_set("classes", value=3), "field 'classes': must be a list of class names"),
    (_set("pair_regions", value=3), "field 'pair_regions': must be a list of region names"),
    (_set("table_class", value=["car"]), "field 'table_class': must be a class name"),
    (_set("units", value=1), "field 'units': must be an object, got int"),
    (_set("regions", value=[]), "field 'regions': must be an object, got list"),
    (_set("reidentification", "sianms", "pairs_true", value="x"),
     "field 'reidentification.sianms.pairs_true': must be a whole number >= 0"),
])
def test_a_table_field_of_the_wrong_type_exits_2_naming_it(runs, folders, change, message):
    evaluation, _ = runs
    folders.edit_table(evaluation, change)
    result = invoke(str(evaluation))
    assert result.exit_code == 2, result.output
    assert result.output.splitlines() == [f"error: {evaluation / 'table.json'}: {message}"]
    assert not (evaluation / "report").exists()


@pytest.mark.parametrize(("change", "message"), [
    (_set("fingerprints", value=None), "field 'fingerprints': must be an object, got NoneType"),
    (_set("timings", "scenes_s", value="abc"), "field 'timings.scenes_s': must be a number of seconds"),
    (_set("eval", value=3), "field 'eval': must be the evaluation folder's path"),
    (_set("regions", "all", "vanilla", "car", "AP", value=10**400),
     "field 'regions.all.vanilla.car.AP': must be a number in [0, 100] or null"),
])
def test_a_damaged_baseline_report_exits_2_naming_its_field(runs, tmp_path, change, message):
    """A gate that crashed would exit 1, which CI reads as a regression."""
    evaluation, _ = runs
    assert invoke(str(evaluation)).exit_code == 0
    content = json.loads((evaluation / "report" / "report.json").read_text())
    change(content)
    baseline = tmp_path / "baseline.json"
    baseline.write_text(json.dumps(content))
    result = invoke(str(evaluation), "--baseline", str(baseline), "--out", str(tmp_path / "r"))
    assert result.exit_code == 2, result.output
    assert result.output.splitlines() == [f"error: {baseline}: {message}"]


def test_a_figure_without_value_is_still_read(runs, folders):
    evaluation, _ = runs
    folders.edit_table(evaluation, _set("regions", "all", "vanilla", "car", "AP", value=None))
    result = invoke(str(evaluation))
    assert result.exit_code == 0, result.output


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
