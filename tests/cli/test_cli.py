import json
import subprocess
import sys

from typer.testing import CliRunner

from sianms_cli import __version__
from sianms_cli.cli import app

runner = CliRunner()


def test_version():
    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0
    assert result.output.strip() == f"sianms {__version__}"


def test_python_dash_m_runs_the_cli():
    result = subprocess.run([sys.executable, "-m", "sianms_cli", "--help"], capture_output=True, text=True)
    assert result.returncode == 0
    assert "synth" in result.stdout and "info" in result.stdout


def test_synth_then_info(tmp_path):
    out = tmp_path / "data"
    result = runner.invoke(app, ["synth", str(out), "--scenes", "1", "--scene-seconds", "1",
                                 "--image-scale", "0.1", "--quiet"])
    assert result.exit_code == 0, result.output
    assert "wrote 1 scenes" in result.output
    result = runner.invoke(app, ["info", str(out), "--json"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output)
    assert summary["scenes"] == 1 and summary["samples"] == 2
    assert summary["lidar_points_per_sweep"]["files"] == 2
    text = runner.invoke(app, ["info", str(out)]).output
    assert "cars in the camera-overlap region" in text


def test_synth_refuses_a_non_empty_folder_with_exit_code_2(tmp_path):
    (tmp_path / "x.txt").write_text("")
    result = runner.invoke(app, ["synth", str(tmp_path), "--scenes", "1"])
    assert result.exit_code == 2
    assert "exists and is not empty; pass --overwrite" in result.output


def test_info_on_a_missing_dataroot_names_the_path(tmp_path):
    result = runner.invoke(app, ["info", str(tmp_path / "nowhere"), "--version", "v1.0-mini"])
    assert result.exit_code == 2
    assert str(tmp_path / "nowhere") in result.output
    assert "Traceback" not in result.output
