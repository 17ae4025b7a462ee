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


def test_info_as_json_and_as_text(synthetic_dataroot, tmp_path):
    dataroot = str(synthetic_dataroot())
    result = runner.invoke(app, ["info", "--dataroot", dataroot, "--json", "--quiet"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output)
    assert summary["scenes"] == 2 and summary["samples"] == 6
    assert summary["lidar_points_per_sweep"]["files"] == 6
    assert summary["image_boxes"]["boxes_3d"] == summary["annotations"]
    assert {"car_azimuth_within_50m", "car_heading_to_axis_within_50m", "ego_motion",
            "nuscenes_reference"} <= set(summary)
    text = runner.invoke(app, ["info", "--dataroot", dataroot, "--quiet"]).output
    assert "cars in the camera-overlap region" in text
    assert "LiDAR points per sweep: mean" in text
    assert "  image boxes (devkit 2-D export rule over 6 cameras):\n    per 3-D box: " in text
    assert " | nuScenes 1.215 (v1.0-trainval, 1,416,337 2-D from 1,166,187 3-D boxes" in text


def test_info_writes_its_figures_to_out_once(synthetic_dataroot, tmp_path):
    dataroot = str(synthetic_dataroot())
    out = tmp_path / "info.json"
    assert runner.invoke(app, ["info", "--dataroot", dataroot, "--quiet", "--out", str(out)]).exit_code == 0
    assert json.loads(out.read_text())["samples"] == 6
    again = runner.invoke(app, ["info", "--dataroot", dataroot, "--quiet", "--out", str(out)])
    assert (again.exit_code, again.output) == (2, f"error: {out} exists; pass --overwrite to replace it\n")


def test_info_max_sweeps(synthetic_dataroot):
    dataroot = str(synthetic_dataroot())
    none = runner.invoke(app, ["info", "--dataroot", dataroot, "--quiet", "--max-sweeps", "0"])
    assert "LiDAR points per sweep: not measured (--max-sweeps 0)" in none.output
    tables_only = runner.invoke(app, ["info", "--dataroot", str(synthetic_dataroot(sensors="none")), "--quiet"])
    assert "LiDAR points per sweep: no LiDAR files" in tables_only.output
    negative = runner.invoke(app, ["info", "--dataroot", dataroot, "--max-sweeps", "-1"])
    assert (negative.exit_code, negative.output) == (2, "error: --max-sweeps must be >= 0 (0 skips the figure), "
                                                        "got -1\n")


def test_synth_refuses_a_non_empty_folder_with_exit_code_2(tmp_path):
    (tmp_path / "x.txt").write_text("")
    result = runner.invoke(app, ["synth", "--out", str(tmp_path), "--scenes", "1"])
    assert result.exit_code == 2
    assert "exists and is not empty; pass --overwrite" in result.output


def test_info_on_a_missing_dataroot_names_the_path(tmp_path):
    result = runner.invoke(app, ["info", "--dataroot", str(tmp_path / "nowhere"), "--version", "v1.0-mini"])
    assert result.exit_code == 2
    assert str(tmp_path / "nowhere") in result.output
    assert "Traceback" not in result.output


def test_escaping_version_is_refused_by_every_command(tmp_path):
    for command in (["info", "--dataroot", str(tmp_path)], ["synth", "--out", str(tmp_path / "x")],
                    ["prepare", "--dataroot", str(tmp_path), "--split", "mini_val", "--out", str(tmp_path / "c")],
                    ["metrics", "--dataroot", str(tmp_path), "--split", "mini_val", "--results", str(tmp_path)]):
        result = runner.invoke(app, [*command, "--version", "../escape"])
        assert result.exit_code == 2, (command, result.output)
        assert result.output.startswith("error: --version must be one folder name"), (command, result.output)
    assert [p.name for p in tmp_path.iterdir()] == []
