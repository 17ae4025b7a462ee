"""`sianms report` as a library: Table I of one evaluation, the regression gate against a baseline, the outputs.

The evaluation folders are written by hand (report_helpers.make_eval), so every figure is known;
the report of a real evaluation is checked in tests/evaluation/test_eval_job.py.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
from pathlib import Path

import pytest
from report_helpers import CONFIG, METHODS, PNG, cell, edit_table, make_eval, parse_html

from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError
from sianms_cli.reporting.eval_table import PAPER_TABLE_I, format_cell, format_ratio
from sianms_cli.reporting.report import DEFAULT_ALLOWANCES, ReportConfig, parse_allowances, run


@pytest.fixture
def evaluation(tmp_path) -> Path:
    return make_eval(tmp_path / "eval")


def test_table_i_in_html_equals_table_json(evaluation):
    report = run(ReportConfig(eval=str(evaluation)))
    assert report.out == evaluation.resolve() / "report" and report.regressions == []
    table = json.loads((evaluation / "table.json").read_text())
    rows = parse_html(report.html).tables["table-i"]
    assert rows[0] == ["region", "method", "AP", "ATE", "ASE", "AOE", "paper AP", "paper ATE", "paper ASE",
                       "paper AOE", "GT boxes", "predictions"]
    expected = []
    for region, label in (("all", "All"), ("overlap", "Overlap")):
        for method in METHODS:
            figures = table["regions"][region][method]["car"]
            paper = PAPER_TABLE_I[label].get(method, (None,) * 4)
            expected.append([label, method + (" (best)" if method == "axis-nms" else ""),
                             *(format_cell(figures[c], c) for c in ("AP", "ATE", "ASE", "AOE")),
                             *(format_cell(v, c) for v, c in zip(paper, ("AP", "ATE", "ASE", "AOE"))),
                             str(figures["gt"]), str(figures["pred"])])
    assert rows[1:] == expected
    assert rows[1][2:6] == ["31.2", "0.612", "24.6", "1.381"] and rows[5][-2] == "66"  # overlap: 66 GT cars
    assert report.content["regions"] == table["regions"]  # every cell of table.json, every class and region
    markdown = (report.out / "report.md").read_text()
    assert markdown == report.markdown and "| All | vanilla | 31.2 | 0.612 | 24.6 | 1.381 | 45.5 |" in markdown


def test_reidentification_duplicates_and_timings(evaluation):
    report = run(ReportConfig(eval=str(evaluation)))
    tables = parse_html(report.html).tables
    assert tables["reidentification"][1] == ["sianms", "60", "43", "48", format_ratio(0.7123), format_ratio(0.8456),
                                             "0.773", "13", "4", "12", "1", "-", "-"]
    assert tables["reidentification"][2][0] == "gated-sianms"
    assert tables["reidentification"][2][-6:] == ["3", "1", "12", "1", "20", "7"]
    # The oracle's figures are those of an evaluation made before the wrong matches were split.
    assert tables["reidentification"][3][-6:] == ["-", "-", "3", "-", "-", "-"]
    assert tables["duplicates"][0] == ["method", "All", "Overlap", "FRONT / FRONT_RIGHT"]
    assert tables["duplicates"][2] == ["axis-nms", "22", "21", "20"]
    assert tables["timings"][1:] == [["scenes", "30.00", "75.0 %"], ["pictures", "5.00", "12.5 %"],
                                     ["metrics_vanilla", "4.50", "11.2 %"], ["select_vanilla", "0.50", "1.2 %"],
                                     ["total", "40.00", "100.0 %"]]
    content = json.loads((report.out / "report.json").read_text())
    assert content == report.content and content["schema"] == "sianms-report" and content["schema_version"] == 1
    assert set(content["config"]) == {"split", "split_scenes", "dataset_sha256", "methods", "nms_sweep", "axis_mode",
                                      "sianms_classes", "max_distance", "seed", "metrics"}
    assert content["fingerprints"]["dis_thr"] == 0.8 and "comparison" not in content


def test_html_is_self_contained_and_embeds_every_picture(tmp_path):
    evaluation = make_eval(tmp_path / "eval", details=True)
    out = tmp_path / "elsewhere" / "report"
    report = run(ReportConfig(eval=str(evaluation)), out)
    page = report.html.read_text()
    assert "http://" not in page and "https://" not in page and "<script" not in page
    parsed = parse_html(report.html)
    sources = [value for name, value in parsed.attributes if name in ("src", "href")]
    assert len(sources) == 3 and all(value.startswith("data:image/png;base64,") for value in sources)
    assert base64.b64decode(sources[2].split(",", 1)[1]) == PNG
    assert sorted(path.name for path in out.iterdir()) == ["pr_curves.png", "report.html", "report.json", "report.md",
                                                           "tp_curves.png"]
    links = [line.split("](")[1].rstrip(")") for line in report.markdown.splitlines() if line.startswith("![")]
    assert links[:2] == ["pr_curves.png", "tp_curves.png"]
    assert all((out / link).resolve().is_file() for link in links)  # the pictures' links reach EVAL/pictures


def test_without_details_the_report_says_so(evaluation):
    report = run(ReportConfig(eval=str(evaluation)))
    assert "No curves: the evaluation has no metrics_details_vanilla.json" in report.markdown
    assert not (report.out / "pr_curves.png").exists()


@pytest.mark.parametrize(("damage", "field"), [
    (lambda folder: (folder / "eval.json").unlink(), "eval.json: file not found"),
    (lambda folder: _edit_marker(folder, kind="sianms-demo"), "eval.json: field 'kind': not a sianms evaluation"),
    (lambda folder: _edit_marker(folder, complete=False, missing_scenes=["scene-0916"]),
     "eval.json: field 'complete': the evaluation is not complete (missing scenes: scene-0916)"),
    (lambda folder: edit_table(folder, lambda t: t["regions"]["overlap"].pop("sianms")),
     "table.json: field 'regions.overlap.sianms.car': missing"),
    (lambda folder: _edit_marker(folder, timings={"scenes_s": "slow"}),
     "eval.json: field 'timings.scenes_s': must be a number of seconds"),
    (lambda folder: (folder / "metrics_vanilla.json").write_text("{}"), "metrics_vanilla.json: field 'cfg': must be"),
    # A traceback before each of these: a list of numbers, a number, null, a huge or a negative cell.
    (lambda folder: _edit_marker(folder, complete=False, missing_scenes=[1]),
     "eval.json: field 'complete': the evaluation is not complete (missing scenes: none; the finish stage"),
    (lambda folder: _edit_marker(folder, complete=False, missing_scenes=5), "(missing scenes: none;"),
    (lambda folder: _edit_marker(folder, config={**CONFIG, "dataset_sha256": None}),
     "eval.json: field 'config.dataset_sha256': must be a string, got NoneType"),
    (lambda folder: _edit_marker(folder, config={**CONFIG, "seed": "one"}),
     "eval.json: field 'config.seed': must be a whole number >= 0"),
    (lambda folder: edit_table(folder, lambda t: t["regions"]["all"]["vanilla"]["car"].update(AP=1e308)),
     "table.json: field 'regions.all.vanilla.car.AP': must be a number in [0, 100] or null"),
    (lambda folder: edit_table(folder, lambda t: t["regions"]["overlap"]["oracle"]["car"].update(AOE=-1)),
     "table.json: field 'regions.overlap.oracle.car.AOE': must be a number in [0, 3.14159] or null"),
    (lambda folder: edit_table(folder, lambda t: t["reidentification"]["sianms"].update(recall=7)),
     "table.json: field 'reidentification.sianms.recall': must be a number in [0, 1] or null"),
])
def test_an_incomplete_or_foreign_evaluation_is_refused(evaluation, damage, field):
    damage(evaluation)
    with pytest.raises(DataFormatError) as caught:
        run(ReportConfig(eval=str(evaluation)))
    assert field in str(caught.value)
    assert not (evaluation / "report").exists()


def _edit_marker(folder: Path, **changes) -> None:
    marker = json.loads((folder / "eval.json").read_text())
    (folder / "eval.json").write_text(json.dumps({**marker, **changes}))


def test_identical_runs_pass_and_every_cell_is_compared(evaluation, tmp_path):
    baseline = make_eval(tmp_path / "baseline", siamese_sha256="0" * 64, dis_thr=0.7)  # fingerprints may differ
    report = run(ReportConfig(eval=str(evaluation), baseline=str(baseline)))
    comparison = report.content["comparison"]
    assert report.regressions == [] and len(comparison["cells"]) == 2 * len(METHODS) * 4
    assert len(comparison["reidentification"]) == 3 * 3
    assert all(row["difference"] == 0 for row in comparison["cells"])
    assert comparison["fingerprints_changed"] == ["dis_thr", "siamese_sha256"]
    assert comparison["allowances"] == dict(DEFAULT_ALLOWANCES)
    assert "No regression beyond the allowances" in report.markdown


def test_a_planted_regression_names_its_cell(evaluation, tmp_path):
    baseline = shutil.copytree(evaluation, tmp_path / "baseline")

    def lower(drop):
        def change(table):
            table["regions"]["overlap"]["sianms"]["car"]["AP"] = cell(2, 1, "car")["AP"] - drop
            table["regions"]["all"]["vanilla"]["car"]["ATE"] = cell(0, 0, "car")["ATE"] + 0.02  # the allowance exactly
        return change

    edit_table(evaluation, lower(1.0))
    report = run(ReportConfig(eval=str(evaluation), baseline=str(baseline)))
    assert [(r["region"], r["method"], r["metric"]) for r in report.regressions] == [("overlap", "sianms", "AP")]
    regression = report.regressions[0]
    assert regression["baseline"] - regression["now"] == pytest.approx(1.0) and regression["allowance"] == 0.5
    assert regression["why"] == "dropped by 1"
    rows = parse_html(report.html).tables
    assert rows["regressions"][1][:3] == ["overlap", "sianms", "AP"]
    assert '<td class="regressed">24.7</td><td class="regressed">-1.0</td>' in report.html.read_text()
    assert run(ReportConfig(eval=str(evaluation), baseline=str(baseline), max_drop="ap=1.5"), overwrite=True
               ).regressions == []
    edit_table(evaluation, lower(0.4))
    assert run(ReportConfig(eval=str(evaluation), baseline=str(baseline)), overwrite=True).regressions == []


def test_errors_rising_and_reidentification_dropping_regress(evaluation, tmp_path):
    baseline = shutil.copytree(evaluation, tmp_path / "baseline")

    def worse(table):
        table["regions"]["all"]["oracle"]["car"]["AOE"] += 0.05
        table["reidentification"]["sianms"]["f1"] -= 0.06
        table["regions"]["overlap"]["vanilla"]["car"]["ASE"] -= 3.0  # an improvement is never a regression

    edit_table(evaluation, worse)
    report = run(ReportConfig(eval=str(evaluation), baseline=str(baseline)))
    assert [(r["region"], r["method"], r["metric"]) for r in report.regressions] == [
        ("all", "oracle", "AOE"), ("re-identification", "sianms", "f1")]


def test_a_missing_figure_regresses_and_no_figure_in_both_is_fine(evaluation, tmp_path):
    baseline = make_eval(tmp_path / "baseline", methods=METHODS + ("hybrid",))

    def blank(table):
        for figures in table["regions"]["overlap"].values():
            figures["car"]["AOE"] = None

    edit_table(evaluation, blank)
    edit_table(baseline, blank)
    with pytest.raises(SianmsError, match=r"differs in: methods\); pass --force"):
        run(ReportConfig(eval=str(evaluation), baseline=str(baseline)))
    report = run(ReportConfig(eval=str(evaluation), baseline=str(baseline), force=True))
    assert {(r["region"], r["method"], r["why"]) for r in report.regressions} == {
        ("all", "hybrid", "no figure now"), ("overlap", "hybrid", "no figure now")}
    assert len(report.regressions) == 4 + 3  # All: AP ATE ASE AOE; Overlap: AOE is None in the baseline too
    assert report.content["comparison"]["config_differences"] == ["methods"]


def test_runs_of_another_config_are_refused_unless_forced(evaluation, tmp_path):
    baseline = make_eval(tmp_path / "baseline", split_scenes=["scene-0103"], seed=2)
    with pytest.raises(SianmsError) as caught:
        run(ReportConfig(eval=str(evaluation), baseline=str(baseline)))
    assert "differs in: split_scenes, seed" in str(caught.value) and not (evaluation / "report").exists()
    report = run(ReportConfig(eval=str(evaluation), baseline=str(baseline), force=True))
    assert report.regressions == [] and report.content["comparison"]["forced"]
    assert "although the configs differ in: split_scenes, seed" in report.markdown


def test_a_report_json_is_a_baseline_equal_to_its_evaluation(evaluation, tmp_path):
    baseline = shutil.copytree(evaluation, tmp_path / "baseline")
    committed = run(ReportConfig(eval=str(baseline)), tmp_path / "expected").out / "report.json"
    edit_table(evaluation, lambda t: t["regions"]["all"]["sianms"]["car"].update(AP=20.0, ATE=0.9))
    from_folder = run(ReportConfig(eval=str(evaluation), baseline=str(baseline)), tmp_path / "a")
    from_json = run(ReportConfig(eval=str(evaluation), baseline=str(committed)), tmp_path / "b")
    for key in ("cells", "reidentification", "config_differences", "fingerprints_changed"):
        assert from_json.content["comparison"][key] == from_folder.content["comparison"][key]
    assert from_json.regressions == from_folder.regressions and len(from_json.regressions) == 2
    again = run(ReportConfig(eval=str(evaluation), baseline=str(from_json.out / "report.json")), tmp_path / "c")
    assert again.content["comparison"]["cells"][0]["baseline"] == from_json.content["comparison"]["cells"][0]["now"]


def test_a_baseline_that_is_no_report_is_refused(evaluation, tmp_path):
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"schema": "sianms-metrics"}))
    with pytest.raises(DataFormatError, match="other.json: field 'schema': not a sianms report"):
        run(ReportConfig(eval=str(evaluation), baseline=str(other)))


@pytest.mark.parametrize(("max_drop", "message"), [
    ("ap=1,speed=2", "--max-drop: unknown key 'speed'; expected ap, ate, ase, aoe, reid"),
    ("ap", "--max-drop: 'ap' is not KEY=VALUE"),
    ("ate=-0.1", "--max-drop: ate=-0.1: must be a number >= 0"),
    ("aoe=fast", "--max-drop: aoe=fast: must be a number >= 0"),
    ("reid=nan", "--max-drop: reid=nan: must be a number >= 0"),
    ("ap=1,ap=2", "--max-drop: 'ap' given twice"),
])
def test_bad_allowances_name_the_flag_and_key(max_drop, message):
    with pytest.raises(SianmsError) as caught:
        ReportConfig(eval="eval", max_drop=max_drop)
    assert str(caught.value).startswith(message)


def test_allowances_start_from_the_defaults():
    assert parse_allowances(" ap=1 , reid=0.1 ") == {**DEFAULT_ALLOWANCES, "ap": 1.0, "reid": 0.1}
    assert dict(ReportConfig(eval="e").max_drop) == dict(DEFAULT_ALLOWANCES)
    with pytest.raises(SianmsError, match="EVAL: must not be empty"):
        ReportConfig(eval=" ")


@pytest.mark.parametrize("flags", [{"max_drop": "ap=1"}, {"force": True}, {"max_drop": "ap=1", "force": True}])
def test_allowances_or_force_without_a_baseline_are_refused(flags):
    """`report E --max-drop ap=1` was accepted and the allowance silently ignored: there is no gate."""
    flag = "--max-drop" if "max_drop" in flags else "--force"
    with pytest.raises(SianmsError, match=f"^{flag}: applies to a comparison, and there is none without --baseline$"):
        ReportConfig(eval="e", **flags)
    assert ReportConfig(eval="e", baseline="b", **flags).baseline == "b"


def test_an_existing_folder_is_replaced_only_when_it_is_a_report_and_asked(tmp_path):
    evaluation = make_eval(tmp_path / "eval", details=True)  # with the curves: every file a report writes
    first = run(ReportConfig(eval=str(evaluation)))
    names = sorted(path.name for path in first.out.iterdir())
    assert names == ["pr_curves.png", "report.html", "report.json", "report.md", "tp_curves.png"]
    before = (first.out / "report.json").read_bytes()
    with pytest.raises(OutputExistsError, match="pass --overwrite"):
        run(ReportConfig(eval=str(evaluation)))
    (first.out / "report.md").write_text("an older report")
    again = run(ReportConfig(eval=str(evaluation)), overwrite=True)
    assert sorted(path.name for path in again.out.iterdir()) == names
    assert (again.out / "report.json").read_bytes() == before
    assert (again.out / "report.md").read_text() != "an older report"
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "keep.txt").write_text("mine")
    with pytest.raises(OutputExistsError, match="not a sianms report"):
        run(ReportConfig(eval=str(evaluation)), foreign, overwrite=True)
    assert (foreign / "keep.txt").read_text() == "mine"
    with pytest.raises(OutputExistsError, match="not a folder"):
        run(ReportConfig(eval=str(evaluation)), foreign / "keep.txt", overwrite=True)
    assert [p.name for p in evaluation.iterdir() if p.name.startswith(".")] == []  # no staging folder left


@pytest.mark.parametrize(("mask", "file_mode", "folder_mode"), [(0o022, 0o644, 0o755), (0o077, 0o600, 0o700)])
def test_outputs_follow_the_umask(evaluation, umask, mask, file_mode, folder_mode):
    umask(mask)
    report = run(ReportConfig(eval=str(evaluation)))
    assert os.stat(report.out).st_mode & 0o777 == folder_mode
    assert {path.name: os.stat(path).st_mode & 0o777 for path in report.out.iterdir()} == dict.fromkeys(
        ["report.json", "report.md", "report.html"], file_mode)


def test_a_baseline_reads_only_the_methods_it_lists(evaluation, tmp_path):
    """A baseline's cells of a method it does not list had been read unchecked: a string there ended in a
    TypeError traceback. They are not its figures: the current run's method counts as new."""
    baseline = make_eval(tmp_path / "baseline", methods=("vanilla", "sianms", "oracle"))
    edit_table(baseline, lambda t: t["regions"]["all"].update({"axis-nms": {"car": {"AP": "high"}}}))
    report = run(ReportConfig(eval=str(evaluation), baseline=str(baseline), force=True))
    rows = [row for row in report.content["comparison"]["cells"] if row["method"] == "axis-nms"]
    assert rows and all(row["baseline"] is None and not row["regressed"] for row in rows)


def test_a_baseline_of_another_table_class_is_refused_even_when_forced(evaluation, tmp_path):
    """A pedestrian Table I had been compared cell by cell against a car one, as regressions."""
    baseline = make_eval(tmp_path / "baseline")
    edit_table(baseline, lambda t: t.update(table_class="pedestrian"))
    for force in (False, True):
        with pytest.raises(DataFormatError) as caught:
            run(ReportConfig(eval=str(evaluation), baseline=str(baseline), force=force))
        assert str(caught.value) == (f"{baseline}: field 'table_class': Table I of 'pedestrian' where "
                                     f"{evaluation}'s is of 'car': no cell compares")


def test_a_link_to_a_report_is_not_replaced(tmp_path):
    """--overwrite onto a link had put a real folder where the link was and left the link, renamed, beside it."""
    evaluation = make_eval(tmp_path / "eval")
    first = run(ReportConfig(eval=str(evaluation)))
    link = tmp_path / "latest"
    link.symlink_to(first.out)
    with pytest.raises(OutputExistsError, match=f"^{link} is a link; give the folder it points to, or another --out$"):
        run(ReportConfig(eval=str(evaluation)), link, overwrite=True)
    assert link.is_symlink() and sorted(path.name for path in tmp_path.iterdir()) == ["eval", "latest"]


def test_a_full_disk_names_the_report_folder_not_its_staging_folder(tmp_path, full_disk):
    """The line had named the hidden staging folder, deleted before the user read it."""
    from sianms_cli.io import OutputError

    evaluation = make_eval(tmp_path / "eval", details=True)
    (full_disk / "pad").write_bytes(bytes(250 * 1024))
    with pytest.raises(OutputError) as raised:
        run(ReportConfig(eval=str(evaluation)), full_disk / "report")
    assert str(raised.value).startswith(f"cannot write {full_disk / 'report'}/") and ".partial" not in str(raised.value)
    assert str(raised.value).endswith("No space left on device")
    assert sorted(path.name for path in full_disk.iterdir()) == ["pad"]
