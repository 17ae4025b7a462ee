"""`sianms train fpointnet` through the CLI: files, --json, per-class lines, refusing, errors as one line."""

import json

import pytest

from typer.testing import CliRunner

from sianms_cli.cli import app

SMALL = ["--num-points", "32", "--num-object-points", "16", "--batch-size", "8", "--min-box-height", "0",
         "--device", "cpu", "--no-jitter"]


def invoke(*arguments):
    return CliRunner().invoke(app, ["train", "fpointnet", *arguments])


def test_train_writes_the_run_and_prints_json(tiny_caches, tmp_path):
    train, val = tiny_caches
    out = tmp_path / "run"
    done = invoke("--cache", str(train), "--val-cache", str(val), "--out", str(out), "--epochs", "1", "--quiet",
                  "--json", *SMALL)
    assert done.exit_code == 0, done.output
    result = json.loads(done.stdout)
    assert result["epochs_run"] == [1] and result["metrics"]["epoch"] == 1
    assert {"val_iou_0.5", "val_iou_0.7", "val_car_center_error", "train_corner"} <= set(result["metrics"])
    assert set(result["mean_sizes_lwh"]) == {"car", "pedestrian", "bicycle"}
    config = json.loads((out / "config.json").read_text())
    assert config["kind"] == "fpointnet" and config["num_points"] == 32 and config["jitter"] is False

    again = invoke("--cache", str(train), "--out", str(out), "--quiet", *SMALL)
    assert again.exit_code == 2 and again.stderr.startswith("error: ") and "--resume" in again.stderr

    resumed = invoke("--cache", str(train), "--val-cache", str(val), "--out", str(out), "--epochs", "2", "--quiet",
                     "--resume", *SMALL)
    assert resumed.exit_code == 0, resumed.output
    assert "trained epochs 2-2" in resumed.stdout and "  car (" in resumed.stdout


def test_a_cache_without_frustums_of_the_classes_is_one_error_line(tiny_caches, tmp_path):
    done = invoke("--cache", str(tiny_caches[0]), "--out", str(tmp_path / "run"), "--classes", "truck", *SMALL)
    assert done.exit_code == 2 and done.stderr.startswith("error: ") and "truck" in done.stderr


def test_streams_too_many_for_the_batch_are_one_error_line(tiny_caches, tmp_path):
    done = invoke("--cache", str(tiny_caches[0]), "--out", str(tmp_path / "run"), *SMALL, "--batch-size", "7",
                  "--streams", "4")
    assert done.exit_code == 2 and done.stderr.strip().splitlines() == [
        "error: --batch-size 7 is too small for 4 streams: each stream's share of a batch needs at least 2"]
    assert not (tmp_path / "run").exists()


def test_a_missing_cache_is_one_error_line(tmp_path):
    done = invoke("--cache", str(tmp_path / "nope"), "--out", str(tmp_path / "run"), *SMALL)
    assert done.exit_code == 2 and done.stderr.strip().splitlines() == [
        f"error: {tmp_path / 'nope' / 'manifest.json'}: not found: not a `sianms prepare` cache "
        "(run `sianms prepare` first)"]


def test_multiview_flags_reach_the_training(tiny_caches, tiny_dataroot, tmp_path):
    train, _ = tiny_caches
    done = invoke("--cache", str(train), "--out", str(tmp_path / "no-root"), "--multiview", "--epochs", "1", *SMALL)
    assert done.exit_code == 2 and done.output.startswith("error:") and "--dataroot" in done.output
    out = tmp_path / "run"
    done = invoke("--cache", str(train), "--out", str(out), "--multiview", "--dataroot", str(tiny_dataroot),
                  "--max-distance", "40", "--epochs", "1", "--quiet", *SMALL)
    assert done.exit_code == 0, done.output
    config = json.loads((out / "config.json").read_text())
    assert config["multiview"] is True and config["max_distance"] == 40.0
    assert (out / "multiview").is_dir()


def test_a_point_count_past_any_frustum_is_refused_as_a_flag(tmp_path):
    """--num-points 1000000000 was accepted and ended in an out-of-memory line after the run began."""
    from sianms_cli.errors import SianmsError
    from sianms_cli.training.fpointnet import FPointNetConfig

    for name in ("num_points", "num_object_points"):
        with pytest.raises(SianmsError, match=f"--{name.replace('_', '-')} must be at most 65,536, got 1000000000"):
            FPointNetConfig(cache=str(tmp_path), **{name: 1_000_000_000})


@pytest.mark.parametrize("epochs", [0, 10_001, 10**20])
def test_an_epoch_count_outside_1_to_10000_is_refused_by_both_trainings(tmp_path, epochs):
    """--epochs 100000000000000000000 was accepted and trained without end."""
    from sianms_cli.errors import SianmsError
    from sianms_cli.training.fpointnet import FPointNetConfig
    from sianms_cli.training.siamese import SiameseConfig

    for config in (FPointNetConfig, SiameseConfig):
        with pytest.raises(SianmsError, match=f"^--epochs must be in \\[1, 10,000\\], got {epochs}$"):
            config(cache=str(tmp_path), epochs=epochs)
