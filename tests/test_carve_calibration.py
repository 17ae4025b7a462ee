"""scripts/carve_calibration.py: a calibration split carved from the training scenes into splits.json."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from sianms_cli.nuscenes.fingerprint import dataset_fingerprint
from sianms_cli.nuscenes.splits import split_scene_names

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "carve_calibration.py"


@pytest.fixture
def dataroot(synthetic_dataroot, tmp_path):
    """A copy of the 5-scene mini's tables (its mini_train holds 4 of them), to write splits.json into."""
    source = synthetic_dataroot(scenes=5, sensors="none")
    shutil.copytree(source / "v1.0-mini", tmp_path / "data" / "v1.0-mini")
    return tmp_path / "data"


def carve(dataroot, *extra):
    return subprocess.run([sys.executable, str(SCRIPT), "--dataroot", str(dataroot), "--version", "v1.0-mini",
                           "--split", "mini_train", *extra], check=False, capture_output=True, text=True)


def test_every_nth_training_scene_goes_to_calibration_and_the_rest_to_fitting(dataroot):
    fingerprint = dataset_fingerprint(dataroot / "v1.0-mini")
    training = [record["name"] for record in json.loads((dataroot / "v1.0-mini" / "scene.json").read_text())
                if record["name"] in split_scene_names("mini_train", "v1.0-mini")]
    assert len(training) == 4
    done = carve(dataroot, "--every", "2")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("calib: 2 scenes, train_fit: 2 scenes (of mini_train) in ")
    assert split_scene_names("calib", "v1.0-mini", dataroot) == training[0::2]
    assert split_scene_names("train_fit", "v1.0-mini", dataroot) == training[1::2]
    assert dataset_fingerprint(dataroot / "v1.0-mini") == fingerprint  # caches of the dataset stay valid
    again = carve(dataroot, "--every", "2")
    assert again.returncode == 0 and again.stdout == done.stdout


def test_a_name_holding_other_scenes_or_a_bad_setting_is_one_error_line(dataroot):
    assert carve(dataroot, "--every", "2").returncode == 0
    path = dataroot / "v1.0-mini" / "splits.json"
    before = path.read_bytes()
    for extra, message in ((["--every", "3"], (f"error: {path}: field 'calib': already defines 'calib' with other "
                                              "scenes")),
                           (["--every", "1"], "error: --every must be at least 2"),
                           (["--every", "5"], "error: split 'mini_train' holds 4 scene(s)"),
                           (["--calibration", "train_calib"], "error: --calibration: 'train_calib' contains 'train'")):
        result = carve(dataroot, *extra)
        assert result.returncode == 2 and result.stdout == "", extra
        assert len(result.stderr.splitlines()) == 1 and result.stderr.startswith(message), result.stderr
    assert path.read_bytes() == before
