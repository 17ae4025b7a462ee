"""examples/make_results.py: ground truth as predictions scores what the devkit's rules say;
perturbations cost what they should; the same seed writes the same bytes."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from sianms_cli.cli import app
from sianms_cli.metrics.evaluate import MetricsConfig, run

REPO_ROOT = Path(__file__).resolve().parents[2]
SCRIPT = REPO_ROOT / "examples" / "make_results.py"
NOISE = "translation=0.5,yaw=0.1,drop=0.2,false-positives=0.3"


def _module(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


make_results = _module("make_results_example", SCRIPT)


@pytest.fixture(scope="module")
def dataroot(tmp_path_factory) -> Path:
    """The small v1.0-mini dataroot of scripts/devkit_metrics_reference.py: 10 categories, boxes
    without points and beyond the ranges, bicycle racks (no trailer, no construction vehicle)."""
    reference = _module("devkit_metrics_reference_examples", REPO_ROOT / "scripts" / "devkit_metrics_reference.py")
    return reference.write_dataroot(tmp_path_factory.mktemp("make_results") / "dataroot")


def _write(dataroot: Path, out: Path, *extra: str) -> Path:
    assert make_results.main(["--dataroot", str(dataroot), "--split", "mini_val", "--out", str(out), *extra]) == 0
    return out


def _metrics(dataroot: Path, results: Path, config: str):
    return run(MetricsConfig(dataroot=str(dataroot), split="mini_val", results=str(results), detection_config=config,
                             regions=("all", "overlap")))


def test_from_the_command_line_to_sianms_metrics(dataroot, tmp_path):
    out = tmp_path / "perfect.json"
    written = subprocess.run([sys.executable, str(SCRIPT), "--dataroot", str(dataroot), "--split", "mini_val",
                              "--out", str(out)], capture_output=True, text=True)
    assert written.returncode == 0, written.stderr
    assert written.stdout == f"wrote 249 boxes to {out}\n"
    result = CliRunner().invoke(app, ["metrics", "--dataroot", str(dataroot), "--split", "mini_val",
                                      "--results", str(out), "--config", "paper", "--quiet"])
    assert result.exit_code == 0, result.output
    assert "mAP 1.0000   NDS 1.0000   over 3 classes" in result.output


def test_perfect_predictions_score_one_on_every_class_with_ground_truth(dataroot, tmp_path):
    results = _write(dataroot, tmp_path / "perfect.json")
    paper = _metrics(dataroot, results, "paper").regions["all"]
    assert paper.classes_without_gt == ()
    assert paper.mean_ap == pytest.approx(1.0, abs=1e-12) and paper.nd_score == pytest.approx(1.0, abs=1e-12)
    assert paper.tp_errors == dict.fromkeys(paper.tp_errors, 0.0)

    devkit = _metrics(dataroot, results, "detection_cvpr_2019")
    everything, overlap = devkit.regions["all"], devkit.regions["overlap"]
    assert everything.classes_without_gt == ("trailer", "construction_vehicle")
    assert overlap.classes_without_gt == ("trailer", "construction_vehicle", "motorcycle", "barrier")
    for region in (everything, overlap):
        assert region.mean_ap_of_classes_with_gt == pytest.approx(1.0, abs=1e-12)
    # The devkit's rule: a class without GT has AP 0 and TP errors 1 and stays in the means. All:
    # 8 of 10 classes score AP 1; orientation leaves out cones (2 of 9 without GT), velocity and
    # attribute also barriers (2 of 8).
    assert everything.mean_ap == pytest.approx(0.8, abs=1e-12)
    assert everything.tp_errors == pytest.approx(
        {"trans_err": 0.2, "scale_err": 0.2, "orient_err": 2 / 9, "vel_err": 0.25, "attr_err": 0.25}, abs=1e-12)
    assert everything.nd_score == pytest.approx((5 * 0.8 + 0.8 + 0.8 + 7 / 9 + 0.75 + 0.75) / 10, abs=1e-12)
    # Overlap: 6 of 10 score AP 1; barrier is exempt from velocity and attribute (3 of 8 without GT).
    assert overlap.mean_ap == pytest.approx(0.6, abs=1e-12)
    assert overlap.nd_score == pytest.approx((5 * 0.6 + 0.6 + 0.6 + 5 / 9 + 5 / 8 + 5 / 8) / 10, abs=1e-12)


def test_perturbed_predictions_score_lower_and_the_seed_decides_the_bytes(dataroot, tmp_path):
    perfect = _metrics(dataroot, _write(dataroot, tmp_path / "perfect.json"), "paper").regions["all"]
    noisy_path = _write(dataroot, tmp_path / "noisy.json", "--perturb", NOISE, "--seed", "4")
    noisy = _metrics(dataroot, noisy_path, "paper").regions["all"]
    assert noisy.mean_ap < perfect.mean_ap - 0.2 and noisy.nd_score < perfect.nd_score - 0.1
    assert noisy.tp_errors["trans_err"] > 0.1 and noisy.tp_errors["orient_err"] > 0.01
    assert noisy.tp_errors["scale_err"] == 0.0  # sizes were not perturbed
    assert sum(noisy.pred_counts.values()) != sum(perfect.pred_counts.values())
    again = _write(dataroot, tmp_path / "again.json", "--perturb", NOISE, "--seed", "4")
    other = _write(dataroot, tmp_path / "other.json", "--perturb", NOISE, "--seed", "5")
    assert again.read_bytes() == noisy_path.read_bytes() != other.read_bytes()


def test_drop_everything_still_lists_every_sample(dataroot, tmp_path):
    out = _write(dataroot, tmp_path / "empty.json", "--perturb", "drop=1,false-positives=2")
    listed = json.loads(out.read_text())["results"]
    assert listed and all(boxes == [] for boxes in listed.values())
    assert _metrics(dataroot, out, "paper").regions["all"].nd_score == 0.0


@pytest.mark.parametrize(("perturb", "message"), [
    ("noise=1", "error: --perturb: unknown key 'noise'; expected KEY=VALUE with KEY one of drop, translation, yaw, "
                "size, velocity, false-positives"),
    ("drop=1.5", "error: --perturb: drop must be in [0, 1], got 1.5"),
    ("yaw=-1", "error: --perturb: yaw must be in [0, 6.28319], got -1"),
    ("yaw=x", "error: --perturb: yaw needs a number, got 'x'"),
    # each had been a traceback (226 TiB asked for), or a warning and an error blamed on the results
    ("false-positives=1e12", "error: --perturb: false-positives must be in [0, 100], got 1e+12"),
    ("size=1000", "error: --perturb: size must be in [0, 3], got 1000"),
    ("velocity=1e200", "error: --perturb: velocity must be in [0, 100], got 1e+200"),
])
def test_a_bad_perturbation_is_named_and_nothing_is_written(dataroot, tmp_path, capsys, perturb, message):
    out = tmp_path / "never.json"
    assert make_results.main(["--dataroot", str(dataroot), "--split", "mini_val", "--out", str(out),
                              "--perturb", perturb]) == 2
    assert capsys.readouterr().err == message + "\n"
    assert not out.exists()


@pytest.mark.parametrize("arguments, message", [
    (["--seed", "-1"], "error: --seed must be between 0 and 2**63 - 1, got -1"),  # had been a traceback
    (["--out", "{dataroot}/v1.0-mini/sample.json", "--overwrite"],  # had replaced the dataset's own table
     "error: --out: {dataroot}/v1.0-mini/sample.json is inside the dataroot {dataroot}, which make_results.py only "
     "reads; write it elsewhere"),
    (["--out", "{tmp}/results/"], "error: --out: {tmp}/results/ names a folder; give the results file's name"),
])
def test_a_bad_seed_or_out_is_one_line_and_nothing_is_written(dataroot, tmp_path, capsys, arguments, message):
    before = sorted(path.name for path in (dataroot / "v1.0-mini").iterdir())
    arguments = [a.format(dataroot=dataroot, tmp=tmp_path) for a in arguments]
    out = [] if "--out" in arguments else ["--out", str(tmp_path / "never.json")]
    assert make_results.main(["--dataroot", str(dataroot), "--split", "mini_val", *out, *arguments]) == 2
    assert capsys.readouterr().err == message.format(dataroot=dataroot, tmp=tmp_path) + "\n"
    assert list(tmp_path.iterdir()) == [] and sorted(path.name for path in (dataroot / "v1.0-mini").iterdir()) == before
