"""`sianms metrics` through the CLI: table, JSON, --out, and one-line errors with exit code 2."""

from __future__ import annotations

import errno
import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from sianms_cli.cli import app

REPO_ROOT = Path(__file__).resolve().parents[2]
runner = CliRunner()


def _reference_script():
    spec = importlib.util.spec_from_file_location("devkit_metrics_reference_cli",
                                                  REPO_ROOT / "scripts" / "devkit_metrics_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def data(synthetic_dataroot, tmp_path_factory) -> dict:
    """A tiny synthetic mini dataroot (3 key frames per scene) and a perturbed results file."""
    reference = _reference_script()
    folder = tmp_path_factory.mktemp("metrics_cli")
    dataroot = synthetic_dataroot(sensors="none")
    results = folder / "results.json"
    results.write_text(json.dumps(reference.make_results(dataroot, "perturbed_mini_val")))
    return {"dataroot": str(dataroot), "results": str(results), "folder": folder}


def invoke(data: dict, *extra: str):
    return runner.invoke(app, ["metrics", "--dataroot", data["dataroot"], "--results", data["results"],
                               "--split", "mini_val", "--quiet", *extra])


def test_prints_a_table_per_region(data):
    result = invoke(data, "--region", "all,overlap")
    assert result.exit_code == 0, result.output
    assert "region all:" in result.output and "region overlap:" in result.output
    assert "AP@0.5" in result.output and "NDS" in result.output and "barrier" in result.output


def test_the_table_marks_classes_without_ground_truth_as_the_devkit_scores_them(data):
    every_pair = json.loads(invoke(data, "--region", "overlap:*", "--json").stdout)["region_boxes"]
    pair = next(name for name, boxes in every_pair.items()  # a pair holding some classes, not all
                if 0 < sum(count > 0 for count in boxes["gt"].values()) < len(boxes["gt"]))
    report = json.loads(invoke(data, "--region", pair, "--json").stdout)
    gt = report["region_boxes"][pair]["gt"]
    without = [name for name, count in gt.items() if count == 0]
    for name in without:
        assert report["regions"][pair]["mean_dist_aps"][name] == 0.0  # the devkit's rule: no GT, AP 0
    lines = invoke(data, "--region", pair).stdout.splitlines()
    assert [line.split()[0] for line in lines if line.split()[1:2] == ["*"]] == without
    mean_ap = report["regions"][pair]["mean_ap"]
    with_gt = [report["regions"][pair]["mean_dist_aps"][name] for name, count in gt.items() if count > 0]
    assert lines[-3] == f"mAP {mean_ap:.4f}   NDS {report['regions'][pair]['nd_score']:.4f}   over {len(gt)} classes"
    assert lines[-2] == (f"* {len(without)} classes without ground truth here: AP 0 and TP errors 1 as in the "
                         "devkit, counted in every mean and NDS")
    plural = "class" if len(with_gt) == 1 else "classes"
    assert lines[-1] == f"  mAP over the {len(with_gt)} {plural} with ground truth: {sum(with_gt) / len(with_gt):.4f}"


def test_json_is_all_there_is_on_stdout(data, tmp_path):
    out = tmp_path / "m.json"
    result = invoke(data, "--json", "--out", str(out))
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout) == json.loads(out.read_text())
    assert result.stderr == f"wrote {out}\n"


def test_help_imports_no_evaluation_code():
    timings = subprocess.run([sys.executable, "-X", "importtime", "-m", "sianms_cli", "metrics", "--help"],
                             capture_output=True, text=True, check=True)
    assert "--results" in timings.stdout and "--overwrite" in timings.stdout
    imported = [line.rsplit("|", 1)[-1].strip() for line in timings.stderr.splitlines()]
    assert "sianms_cli.cli.metrics" in imported
    assert not [name for name in imported if name.startswith(("sianms_cli.metrics", "sianms_cli.reporting"))]


def test_json_output_and_paper_config(data):
    result = invoke(data, "--json", "--config", "paper", "--region", "overlap:*")
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert report["schema"] == "sianms-metrics" and report["config"] == "paper"
    assert all(name.startswith("overlap:CAM_") for name in report["regions"])
    assert len(report["regions"]) == 6
    assert list(report["regions"]["overlap:CAM_FRONT|CAM_FRONT_RIGHT"]["label_aps"]) == ["car", "pedestrian", "bicycle"]


def test_out_is_written_once_then_needs_overwrite(data, tmp_path):
    out = tmp_path / "m.json"
    first = invoke(data, "--out", str(out))
    assert first.exit_code == 0, first.output
    assert f"wrote {out}" in first.output
    assert json.loads(out.read_text())["regions"]["all"]["cfg"]["dist_th_tp"] == 2.0
    again = invoke(data, "--out", str(out))
    assert again.exit_code == 2 and "--overwrite" in again.output
    assert invoke(data, "--out", str(out), "--overwrite").exit_code == 0


def test_details_hold_every_region_and_need_overwrite(data, tmp_path):
    details, out = tmp_path / "details.json", tmp_path / "m.json"
    result = invoke(data, "--region", "all,overlap", "--details", str(details), "--out", str(out), "--json")
    assert result.exit_code == 0, result.output
    assert result.stderr.splitlines() == [f"wrote {out}", f"wrote {details}"]
    curves = json.loads(details.read_text())
    assert list(curves) == ["all", "overlap"] and "car:0.5" in curves["all"] and "barrier:4.0" in curves["overlap"]
    assert set(curves["all"]["car:2.0"]) == {"recall", "precision", "confidence", "trans_err", "vel_err",
                                              "scale_err", "orient_err", "attr_err"}
    assert invoke(data, "--details", str(details)).exit_code == 2
    assert invoke(data, "--details", str(details), "--overwrite").exit_code == 0
    result = invoke(data, "--details", str(out), "--out", str(out), "--overwrite")
    assert result.exit_code == 2 and "--details: " in result.output and "is also --out" in result.output


def test_user_config_file(data, tmp_path):
    config = tmp_path / "cfg.json"
    config.write_text(json.dumps({"class_range": {"car": 20, "traffic_cone": 25}}))
    result = invoke(data, "--config", str(config), "--json")
    assert result.exit_code == 0, result.output
    assert list(json.loads(result.output)["regions"]["all"]["label_aps"]) == ["car", "traffic_cone"]
    config.write_text(json.dumps({"class_range": {"cyclist": 40}}))
    result = invoke(data, "--config", str(config))
    assert result.exit_code == 2
    assert str(config) in result.output and "class_range.cyclist" in result.output


@pytest.mark.parametrize(("change", "expected"), [
    (lambda doc: doc["results"][next(iter(doc["results"]))].append({"sample_token": "x"}), "field 'translation'"),
    (lambda doc: doc["results"].popitem(), "missing (1 of"),
    (lambda doc: doc.pop("meta"), "no 'meta' object"),
])
def test_bad_results_end_in_one_line_and_exit_2(data, tmp_path, change, expected):
    document = json.loads(Path(data["results"]).read_text())
    change(document)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(document))
    out = tmp_path / "never.json"
    result = runner.invoke(app, ["metrics", "--dataroot", data["dataroot"], "--results", str(bad), "--split",
                                 "mini_val", "--out", str(out), "--quiet"])
    assert result.exit_code == 2
    assert expected in result.output and str(bad) in result.output
    assert "Traceback" not in result.output and len(result.output.strip().splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize(("options", "expected"), [
    (["--split", "val"], "needs a dataset version ending in 'trainval'"),
    (["--split", "mini_val", "--region", "overlap:CAM_FRONT|CAM_BACK"], "unknown region 'overlap:CAM_FRONT|CAM_BACK'"),
    (["--split", "mini_val", "--region", "all,front"], "error: --region: unknown region 'front'; expected all,"),
    (["--split", "mini_val", "--config", "nope"], "error: --config: 'nope' is neither a preset"),
])
def test_bad_options_exit_2(data, options, expected):
    result = runner.invoke(app, ["metrics", "--dataroot", data["dataroot"], "--results", data["results"],
                                 "--quiet", *options])
    assert result.exit_code == 2, result.output
    assert expected in result.output


def test_out_in_a_read_only_folder_is_one_error_line(data, read_only_folder):
    out = read_only_folder / "m.json"
    result = invoke(data, "--out", str(out))
    assert (result.exit_code, result.output) == (2, f"error: cannot write {out}: Read-only file system\n")


def test_out_naming_a_folder_is_refused_before_any_work(data, tmp_path):
    result = invoke(data, "--out", str(tmp_path))
    assert (result.exit_code, result.output) == (2, f"error: cannot write {tmp_path}: it is a folder\n")


def test_details_that_cannot_be_written_leave_no_out(data, tmp_path):
    (tmp_path / "blocker").write_text("a file where --details wants a folder")
    out, details = tmp_path / "m.json", tmp_path / "blocker" / "d.json"
    result = invoke(data, "--out", str(out), "--details", str(details))
    assert (result.exit_code, result.output) == (2, f"error: cannot write {tmp_path / 'blocker'}: not a folder\n")
    assert sorted(os.listdir(tmp_path)) == ["blocker"]  # no m.json, no temporary file


def test_a_full_disk_while_writing_details_leaves_neither_file_nor_replaces_any(data, tmp_path, monkeypatch):
    from sianms_cli import io

    out, details = tmp_path / "m.json", tmp_path / "d.json"

    class FullDisk:  # the stream of d.json: every write fails as on a full disk
        def __init__(self, stream):
            self.stream = stream

        def write(self, data):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        def flush(self):
            pass

        def close(self):
            self.stream.close()

    opened = io.AtomicFile.__init__

    def open_on_a_full_disk(self, path, **options):
        opened(self, path, **options)
        if self.path == details:
            self.stream = FullDisk(self.stream)

    monkeypatch.setattr(io.AtomicFile, "__init__", open_on_a_full_disk)
    expected = (2, f"error: cannot write {details}: No space left on device\n")
    result = invoke(data, "--out", str(out), "--details", str(details))
    assert (result.exit_code, result.output) == expected
    assert sorted(os.listdir(tmp_path)) == []
    monkeypatch.undo()
    assert invoke(data, "--out", str(out), "--details", str(details)).exit_code == 0
    before = {path.name: path.read_bytes() for path in (out, details)}
    monkeypatch.setattr(io.AtomicFile, "__init__", open_on_a_full_disk)
    result = invoke(data, "--out", str(out), "--details", str(details), "--region", "all,overlap", "--overwrite")
    assert (result.exit_code, result.output) == expected
    assert {path.name: path.read_bytes() for path in tmp_path.iterdir()} == before  # the earlier pair, untouched
