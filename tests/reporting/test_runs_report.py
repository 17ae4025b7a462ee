"""`sianms report EVAL EVAL ...`: Table I over runs, paired differences, re-identification, refusals."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from report_helpers import cell, edit_table, make_eval, parse_html
from typer.testing import CliRunner

from sianms_cli.cli import app
from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError
from sianms_cli.reporting.report import ReportConfig
from sianms_cli.reporting.report import run as report_run
from sianms_cli.reporting.runs_report import RunsReportConfig, run

METHODS = ("vanilla", "axis-nms", "axis-nms@0.1", "sianms", "oracle")
SIANMS_AP_SHIFT = (1.0, -4.0, 4.0)  # added to siaNMS's AP in run k, both regions
PRECISION = (0.7, 0.8, 0.9)
T_975_2 = 4.302652729911275  # Student's t, 97.5 % quantile, 2 degrees of freedom


def make_run(tmp_path, k: int, **config):
    """Run k of three: seed k on its own dataset; siaNMS's AP shifted by SIANMS_AP_SHIFT[k]; in run 1 the best
    Axis-NMS threshold is 0.1."""
    folder = make_eval(tmp_path / f"run{k}", methods=METHODS, seed=k, dataset_sha256=f"{k}" * 64, **config)

    def change(table):
        for region in ("all", "overlap"):
            table["regions"][region]["sianms"]["car"]["AP"] += SIANMS_AP_SHIFT[k]
            table["regions"][region]["vanilla"]["car"]["gt"] += k
        table["best_nms"] = {"axis-nms": "axis-nms@0.1" if k == 1 else "axis-nms"}
        table["reidentification"]["sianms"]["precision"] = PRECISION[k]
    edit_table(folder, change)
    return folder


@pytest.fixture
def runs(tmp_path):
    return [make_run(tmp_path, k) for k in range(3)]


def test_cells_are_mean_and_sample_spread_with_each_runs_best(runs, tmp_path):
    content = run(RunsReportConfig(evals=tuple(map(str, runs))), tmp_path / "out").content
    sianms = content["cells"]["overlap"]["sianms"]["AP"]
    expected = [cell(3, 1, "car")["AP"] + shift for shift in SIANMS_AP_SHIFT]
    assert sianms["values"] == pytest.approx(expected)
    assert sianms["mean"] == pytest.approx(np.mean(expected))
    assert sianms["sd"] == pytest.approx(np.std(expected, ddof=1))
    assert sianms["n"] == 3
    best = content["cells"]["all"]["axis-nms (best)"]["AP"]["values"]  # axis-nms is method 1, axis-nms@0.1 method 2
    assert best == pytest.approx([cell(1, 0, "car")["AP"], cell(2, 0, "car")["AP"], cell(1, 0, "car")["AP"]])
    assert list(content["cells"]["all"]) == ["vanilla", "axis-nms", "axis-nms (best)", "axis-nms@0.1", "sianms",
                                              "oracle"]
    assert content["cells"]["all"]["vanilla"]["gt"] == [605, 606, 607]
    assert [r["seed"] for r in content["runs"]] == [0, 1, 2] and content["runs"][2]["gt"] == {"all": 607, "overlap": 68}


def test_paired_differences_have_a_t_interval_and_count_the_better_runs(runs, tmp_path):
    content = run(RunsReportConfig(evals=tuple(map(str, runs))), tmp_path / "out").content
    entry = next(e for e in content["paired_differences"]
                 if (e["method"], e["reference"], e["region"]) == ("sianms", "vanilla", "overlap"))
    differences = [cell(3, 1, "car")["AP"] - cell(0, 1, "car")["AP"] + shift for shift in SIANMS_AP_SHIFT]
    ap = entry["AP"]
    assert ap["values"] == pytest.approx(differences)
    half = T_975_2 * np.std(differences, ddof=1) / math.sqrt(3)
    assert ap["ci95"] == pytest.approx([np.mean(differences) - half, np.mean(differences) + half])
    assert ap["better"] == 2  # 4.33, -0.67, 7.33 points
    ate = entry["ATE"]  # siaNMS's ATE is 0.03 m above vanilla's in every run: worse, with no spread
    assert ate["values"] == pytest.approx([0.03] * 3) and ate["sd"] == pytest.approx(0.0) and ate["better"] == 0
    pairs = {(e["method"], e["reference"]) for e in content["paired_differences"]}
    assert pairs == {(m, r) for m in ("sianms", "oracle") for r in ("vanilla", "axis-nms", "axis-nms (best)")}


def test_reidentification_over_runs(runs, tmp_path):
    reid = run(RunsReportConfig(evals=tuple(map(str, runs))), tmp_path / "out").content["reidentification"]
    assert reid["sianms"]["precision"]["mean"] == pytest.approx(0.8)
    assert reid["sianms"]["precision"]["sd"] == pytest.approx(0.1)
    assert reid["sianms"]["pairs_true"] == [48, 48, 48] and set(reid) == {"sianms", "gated-sianms", "oracle"}


def test_markdown_and_html_hold_the_same_tables(runs, tmp_path):
    report = run(RunsReportConfig(evals=tuple(map(str, runs))), tmp_path / "out")
    tables = parse_html(report.html).tables
    row = next(r for r in tables["paired-differences"] if r[:2] == ["sianms − vanilla", "Overlap"])
    assert row[2] == "+3.7 ± 4.0" and row[-1] == "2 of 3"
    assert "| sianms − vanilla | Overlap | +3.7 ± 4.0 |" in report.markdown
    table_row = next(r for r in tables["table-i"] if r[:2] == ["All", "vanilla"])
    assert table_row[2] == "31.2 ± 0.0" and table_row[-1] == "605, 606, 607"
    assert json.loads((report.out / "report.json").read_text()) == report.content


def test_a_runs_report_json_counts_as_its_run(runs, tmp_path):
    saved = report_run(ReportConfig(eval=str(runs[2])), tmp_path / "saved").out / "report.json"
    from_folders = run(RunsReportConfig(evals=tuple(map(str, runs))), tmp_path / "a").content
    from_json = run(RunsReportConfig(evals=(str(runs[0]), str(runs[1]), str(saved))), tmp_path / "b").content
    assert from_json["cells"] == from_folders["cells"]
    assert from_json["paired_differences"] == from_folders["paired_differences"]


def test_a_run_without_a_figure_is_left_out_of_that_cell(runs, tmp_path):
    def no_overlap_truth(table):
        for method in METHODS:
            table["regions"]["overlap"][method]["car"].update(AP=None, ATE=None, ASE=None, AOE=None, gt=0)
    edit_table(runs[1], no_overlap_truth)
    content = run(RunsReportConfig(evals=tuple(map(str, runs))), tmp_path / "out").content
    ap = content["cells"]["overlap"]["sianms"]["AP"]
    assert ap["n"] == 2 and ap["values"][1] is None
    entry = next(e for e in content["paired_differences"]
                 if (e["method"], e["reference"], e["region"]) == ("sianms", "vanilla", "overlap"))
    assert entry["AP"]["n"] == 2 and entry["AP"]["better"] == 2


def test_runs_evaluated_otherwise_or_given_twice_are_refused(runs, tmp_path):
    other = make_eval(tmp_path / "other", methods=METHODS[:-1], seed=5, dataset_sha256="5" * 64)
    with pytest.raises(SianmsError, match=r"EVAL: .*other was evaluated otherwise .*differs in: methods"):
        run(RunsReportConfig(evals=(str(runs[0]), str(other))), tmp_path / "out")
    with pytest.raises(SianmsError, match="is the same run as"):
        run(RunsReportConfig(evals=(str(runs[0]), str(runs[1]), str(runs[0]))), tmp_path / "out")
    with pytest.raises(SianmsError, match="at least two"):
        RunsReportConfig(evals=(str(runs[0]),))
    (runs[1] / "eval.json").unlink()
    with pytest.raises(DataFormatError, match="eval.json"):
        run(RunsReportConfig(evals=tuple(map(str, runs))), tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_an_existing_folder_is_replaced_only_when_it_is_a_report_and_asked(runs, tmp_path):
    config = RunsReportConfig(evals=tuple(map(str, runs)))
    out = run(config, tmp_path / "out").out
    with pytest.raises(OutputExistsError, match="--overwrite"):
        run(config, out)
    assert run(config, out, overwrite=True).out == out
    (out / "notes.txt").write_text("mine")
    with pytest.raises(OutputExistsError) as caught:
        run(config, out, overwrite=True)
    assert str(caught.value) == (f"{out}: not replaced: 'notes.txt' is not something sianms report writes; remove it "
                                 "yourself or choose another --out")
    assert (out / "notes.txt").read_text() == "mine"
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("mine")
    with pytest.raises(OutputExistsError, match="not a sianms report"):
        run(config, tmp_path / "mine", overwrite=True)


def test_cli_several_evals(runs, tmp_path):
    cli = CliRunner()
    result = cli.invoke(app, ["report", *map(str, runs), "--out", str(tmp_path / "out"), "--quiet", "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["schema"] == "sianms-runs-report"
    out = ["--out", str(tmp_path / "x")]
    for arguments, message in ((out + ["--baseline", str(runs[0])], "error: --baseline: the gate compares one"),
                               (out + ["--force"], "error: --force: the gate compares one"),
                               ([], "error: --out: a report over several runs has no EVAL folder")):
        result = cli.invoke(app, ["report", *map(str, runs), *arguments, "--quiet"])
        lines = result.output.strip().splitlines()
        assert result.exit_code == 2 and len(lines) == 1 and lines[0].startswith(message), result.output
    assert not (tmp_path / "x").exists()


def test_a_difference_that_rounds_to_nothing_has_no_minus_sign():
    from sianms_cli.reporting.runs_report import _plus_minus

    stats = {"mean": -0.0004, "sd": 0.0, "ci95": [-0.0004, -0.0004], "n": 3}
    assert _plus_minus(stats, "AOE", signed=True) == "+0.000 ± 0.000"
    assert _plus_minus({**stats, "mean": -0.04}, "AP", signed=True) == "+0.0 ± 0.0"


def test_a_run_whose_table_lists_other_methods_than_its_config_is_refused(runs, tmp_path):
    """Runs were compared by their configs' methods, their rows taken from table.json's: a KeyError."""
    def drop_oracle(table):
        table["methods"].remove("oracle")
        for region in table["regions"].values():
            region.pop("oracle")
    edit_table(runs[2], drop_oracle)
    with pytest.raises(SianmsError, match=r"run2 was evaluated otherwise .*differs in: the methods of table.json"):
        run(RunsReportConfig(evals=tuple(map(str, runs))), tmp_path / "out")


ARM_SHIFT = (2.0, 0.5, -1.0)  # added to the second arm's oracle AP on world k, overlap only


def make_second_arm(tmp_path, k: int, **config):
    """World k evaluated again with another detector: the oracle's overlap AP shifted by ARM_SHIFT[k]."""
    folder = make_eval(tmp_path / f"arm{k}", methods=METHODS, seed=k, dataset_sha256=f"{k}" * 64,
                       fpointnet_sha256="g" * 64, **config)

    def change(table):
        table["regions"]["overlap"]["oracle"]["car"]["AP"] += ARM_SHIFT[k]
        table["best_nms"] = {"axis-nms": "axis-nms@0.1" if k == 2 else "axis-nms"}
    edit_table(folder, change)
    return folder


def test_a_second_arm_is_compared_world_by_world(runs, tmp_path):
    arm = [make_second_arm(tmp_path, k) for k in range(3)]
    shuffled = (runs[2], runs[0], runs[1])  # paired by dataset and seed, not by order
    report = run(RunsReportConfig(evals=tuple(map(str, arm)), paired_with=tuple(map(str, shuffled))),
                 tmp_path / "out")
    paired = report.content["paired"]
    assert [r["source"] for r in paired["runs"]] == list(map(str, runs))
    entry = next(e for e in paired["differences"] if (e["method"], e["region"]) == ("oracle", "overlap"))
    assert entry["AP"]["values"] == pytest.approx(ARM_SHIFT)
    half = T_975_2 * np.std(ARM_SHIFT, ddof=1) / math.sqrt(3)
    assert entry["AP"]["ci95"] == pytest.approx([np.mean(ARM_SHIFT) - half, np.mean(ARM_SHIFT) + half])
    assert entry["AP"]["better"] == 2
    siamese = next(e for e in paired["differences"] if (e["method"], e["region"]) == ("sianms", "overlap"))
    assert siamese["AP"]["values"] == pytest.approx([-1.0, 4.0, -4.0])  # the first arm's shifts, taken away
    best = next(e for e in paired["differences"] if (e["method"], e["region"]) == ("axis-nms (best)", "all"))
    # each arm at its own best: world 1 is 0.3 against 0.1, world 2 is 0.1 against 0.3
    assert best["AP"]["values"] == pytest.approx([0.0, cell(1, 0, "car")["AP"] - cell(2, 0, "car")["AP"],
                                                  cell(2, 0, "car")["AP"] - cell(1, 0, "car")["AP"]])
    assert [other["differs_in"] for other in paired["runs"]] == [["fpointnet_sha256"]] * 3
    tables = parse_html(report.html).tables
    assert [row[2] for row in tables["paired-runs"][1:]] == [str(runs[0]), str(runs[1]), str(runs[2])]
    row = next(r for r in tables["arm-differences"] if r[:2] == ["oracle", "Overlap"])
    assert row[2] == "+0.5 ± 1.5" and row[-1] == "2 of 3"
    assert "| oracle | Overlap | +0.5 ± 1.5 |" in report.markdown
    assert run(RunsReportConfig(evals=tuple(map(str, runs))), tmp_path / "alone").content["paired"] is None


def test_a_second_arm_that_is_not_one_run_per_world_evaluated_alike_is_refused(runs, tmp_path):
    arm = [make_second_arm(tmp_path, k) for k in range(3)]

    def report(evals, paired_with):
        return run(RunsReportConfig(evals=tuple(map(str, evals)), paired_with=tuple(map(str, paired_with))),
                   tmp_path / "out")
    with pytest.raises(SianmsError, match="--paired-with: 2 runs for 3 EVAL"):
        report(arm, runs[:2])
    elsewhere = make_eval(tmp_path / "elsewhere", methods=METHODS, seed=7, dataset_sha256="7" * 64)
    with pytest.raises(SianmsError, match=r"--paired-with: no run on the dataset and seed of .*arm2 \(dataset "
                                          r"222222222222, seed 2\)"):
        report(arm, (runs[0], runs[1], elsewhere))
    with pytest.raises(SianmsError, match=r"--paired-with: .*run0 is the same run as .*run0 \(same cache"):
        report(runs, runs)
    swept = [make_eval(tmp_path / f"swept{k}", methods=METHODS, seed=k, dataset_sha256=f"{k}" * 64,
                       nms_sweep="0.1", fpointnet_sha256="g" * 64) for k in range(3)]
    with pytest.raises(SianmsError, match="evaluated otherwise .*differs in: nms_sweep"):
        report(swept, runs)
    assert not (tmp_path / "out").exists()


def test_cli_paired_with(runs, tmp_path):
    arm = [make_second_arm(tmp_path, k) for k in range(3)]
    pairing = [word for folder in runs for word in ("--paired-with", str(folder))]
    cli = CliRunner()
    result = cli.invoke(app, ["report", *map(str, arm), *pairing, "--out", str(tmp_path / "out"), "--quiet",
                              "--json"])
    assert result.exit_code == 0, result.output
    assert len(json.loads(result.stdout)["paired"]["differences"]) == 2 * 6  # six rows, two regions
    result = cli.invoke(app, ["report", str(arm[0]), "--paired-with", str(runs[0]), "--quiet"])
    assert (result.exit_code, result.output) == (
        2, "error: --paired-with: arms are compared over several runs; give at least two EVAL\n")
