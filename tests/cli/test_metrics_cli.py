"""`sianms metrics` through the CLI: table, JSON, --out, and one-line errors with exit code 2."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from sianms_cli.cli import app
from sianms_cli.synth.generate import SynthConfig, synthesize

REPO_ROOT = Path(__file__).resolve().parents[2]
runner = CliRunner()


def _reference_script():
    spec = importlib.util.spec_from_file_location("devkit_metrics_reference_cli",
                                                  REPO_ROOT / "scripts" / "devkit_metrics_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> dict:
    """A tiny synthetic mini dataroot (3 key frames per scene) and a perturbed results file."""
    reference = _reference_script()
    folder = tmp_path_factory.mktemp("metrics_cli")
    dataroot = synthesize(folder / "dataroot", SynthConfig(scenes=2, image_scale=0.1, scene_seconds=1.5, seed=3,
                                                            sensors="none"), progress=False)
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


def test_json_output_and_paper_config(data):
    result = invoke(data, "--json", "--config", "paper", "--region", "overlap:*")
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert report["config"] == "paper"
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
    (["--split", "mini_val", "--region", "overlap:CAM_FRONT|CAM_BACK"], "unknown region"),
    (["--split", "mini_val", "--config", "nope"], "neither a preset"),
])
def test_bad_options_exit_2(data, options, expected):
    result = runner.invoke(app, ["metrics", "--dataroot", data["dataroot"], "--results", data["results"],
                                 "--quiet", *options])
    assert result.exit_code == 2, result.output
    assert expected in result.output
