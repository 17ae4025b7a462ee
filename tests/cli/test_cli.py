import json
import shutil
import subprocess
import sys

from typer.testing import CliRunner

from sianms_cli import __version__
from sianms_cli.cli import app
from sianms_cli.provenance import numeric_platform
from sianms_cli.reporting.dataset_summary import _synth_marker_lines

runner = CliRunner()


def test_version_then_the_numeric_platform():
    from importlib import metadata

    result = runner.invoke(app, ["--version"])
    here = numeric_platform()
    assert result.exit_code == 0
    assert result.output == (f"sianms {__version__}\n{here['cpu_vendor']} {here['vector_width']} CPU, "
                             f"{here['kernels']} kernels; Python {here['python']}, numpy {here['numpy']}, "
                             f"numba {here['numba']}, torch {metadata.version('torch')}\n")


def test_python_dash_m_runs_the_cli():
    result = subprocess.run([sys.executable, "-m", "sianms_cli", "--help"], capture_output=True, text=True)
    assert result.returncode == 0
    assert "synth" in result.stdout and "info" in result.stdout


def sianms(*arguments):
    return subprocess.run([sys.executable, "-m", "sianms_cli", *arguments], capture_output=True, text=True)


def test_a_flag_the_parser_refuses_is_one_error_line():
    bad_type = sianms("synth", "--seed", "abc")
    assert bad_type.returncode == 2 and bad_type.stdout == ""
    [line] = bad_type.stderr.splitlines()  # the parser's own wording between these two ends
    assert line.startswith("error: sianms synth: Invalid value for '--seed': ")
    assert line.endswith("(see 'sianms synth -h')")
    out_of_range = sianms("train", "siamese", "--cache", "c", "--out", "r", "--threads", "0")
    assert out_of_range.returncode == 2 and len(out_of_range.stderr.splitlines()) == 1
    assert out_of_range.stderr.startswith("error: sianms train siamese: Invalid value for '--threads'")
    unknown = sianms("info", "--bogus")
    assert unknown.returncode == 2 and unknown.stderr.startswith("error: sianms info: No such option: --bogus")


def test_a_bare_command_group_prints_its_help_then_one_error_line():
    for group, subcommand in ((("train",), "siamese"), ((), "synth")):
        bare = sianms(*group)
        path = " ".join(("sianms", *group))
        assert bare.returncode == 2 and subcommand in bare.stderr and bare.stdout == ""
        assert bare.stderr.splitlines()[-1] == f"error: {path}: missing command. (see '{path} -h')"
        assert bare.stderr.count("error:") == 1


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
    assert summary["scene_conditions"] == {"night": 0, "rain": 0, "night_and_rain": 0, "share_night": 0.0,
                                           "share_rain": 0.0, "share_night_and_rain": 0.0}  # seed 3: two dry days
    text = runner.invoke(app, ["info", "--dataroot", dataroot, "--quiet"]).output
    assert "cars in the camera-overlap region" in text
    assert "  scenes at night (description): 0 of 2, 0.0 % | nuScenes 11.6 % (" in text
    assert "LiDAR points per sweep: mean" in text
    assert "  image boxes (devkit 2-D export rule over 6 cameras):\n    per 3-D box: " in text
    assert " | nuScenes 1.215 (v1.0-trainval, 1,416,337 2-D from 1,166,187 3-D boxes" in text
    here = numeric_platform()
    assert summary["synth_marker"]["config"]["seed"] == 3 and summary["synth_marker"]["platform"] == here
    assert (f"\n  written by sianms synth {__version__} (seed 3), on {here['cpu_vendor']} {here['vector_width']}, "
            f"{here['kernels']} kernels, numpy {here['numpy']}, numba {here['numba']}\n") in text


def test_info_says_who_wrote_a_synthetic_dataroot_and_nothing_for_another():
    old = {"kind": "sianms synth dataroot", "sianms_version": "0.1.0", "config": {"seed": 7}}
    assert _synth_marker_lines(old) == ["  written by sianms synth 0.1.0 (seed 7), platform not recorded"]
    before_kernels = {**old, "platform": {"cpu_vendor": "GenuineIntel", "vector_width": "AVX512", "numpy": "2.4.6",
                                          "numba": "0.68.1"}}
    assert _synth_marker_lines(before_kernels) == [
        "  written by sianms synth 0.1.0 (seed 7), on GenuineIntel AVX512, numpy 2.4.6, numba 0.68.1"]
    assert _synth_marker_lines(None) == []


def test_info_writes_its_figures_to_out_once(synthetic_dataroot, tmp_path):
    dataroot = str(synthetic_dataroot())
    out = tmp_path / "info.json"
    assert runner.invoke(app, ["info", "--dataroot", dataroot, "--quiet", "--out", str(out)]).exit_code == 0
    assert json.loads(out.read_text())["samples"] == 6
    again = runner.invoke(app, ["info", "--dataroot", dataroot, "--quiet", "--out", str(out)])
    assert (again.exit_code, again.output) == (2, f"error: {out} exists; pass --overwrite to replace it\n")


def test_info_never_writes_into_the_dataroot(synthetic_dataroot):
    """`info --out D/v1.0-mini/sample.json --overwrite` replaced the dataset's own sample table."""
    dataroot = synthetic_dataroot()
    table = dataroot / "v1.0-mini" / "sample.json"
    before = table.read_bytes()
    for flag, path in (("--out", table), ("--contact-sheet", dataroot / "samples" / "sheet.png")):
        result = runner.invoke(app, ["info", "--dataroot", str(dataroot), "--quiet", "--overwrite", flag, str(path)])
        assert (result.exit_code, result.output) == (2, f"error: {flag}: {path} is inside the dataroot {dataroot}, "
                                                        "which info only reads; write it elsewhere\n")
    assert table.read_bytes() == before and not (dataroot / "samples" / "sheet.png").exists()


def test_info_max_sweeps(synthetic_dataroot):
    dataroot = str(synthetic_dataroot())
    none = runner.invoke(app, ["info", "--dataroot", dataroot, "--quiet", "--max-sweeps", "0"])
    assert "LiDAR points per sweep: not measured (--max-sweeps 0)" in none.output
    tables_only = runner.invoke(app, ["info", "--dataroot", str(synthetic_dataroot(sensors="none")), "--quiet"])
    assert "LiDAR points per sweep: no LiDAR files" in tables_only.output
    negative = runner.invoke(app, ["info", "--dataroot", dataroot, "--max-sweeps", "-1"])
    assert (negative.exit_code, negative.output) == (2, "error: --max-sweeps must be >= 0 (0 skips the figure), "
                                                        "got -1\n")


def test_a_missing_lidar_file_is_one_error_line_even_when_it_is_the_first(synthetic_dataroot, tmp_path):
    """Not read as a tables-only dataset; and with the bar on, stderr that is not a terminal gets
    the error line alone (a bar's carriage returns would stand in front of it)."""
    dataroot = tmp_path / "data"
    shutil.copytree(synthetic_dataroot(), dataroot)
    sample_data = json.loads((dataroot / "v1.0-mini" / "sample_data.json").read_text())
    first = next(r for r in sample_data if r["is_key_frame"] and r["filename"].startswith("samples/LIDAR_TOP/"))
    (dataroot / first["filename"]).unlink()
    result = subprocess.run([sys.executable, "-m", "sianms_cli", "info", "--dataroot", str(dataroot)],
                            capture_output=True, text=True)
    assert (result.returncode, result.stderr) == (
        2, f"error: {dataroot / first['filename']}: record {first['token']}: lidar file not found\n")


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


def test_info_draws_a_contact_sheet_of_the_conditions_it_has(synthetic_dataroot, tmp_path):
    from PIL import Image

    dataroot = str(synthetic_dataroot())
    sheet = tmp_path / "sheet.png"
    result = runner.invoke(app, ["info", "--dataroot", dataroot, "--quiet", "--max-sweeps", "0",
                                 "--contact-sheet", str(sheet)])
    assert result.exit_code == 0, result.output
    assert f"contact sheet: {sheet} (day scene-" in result.output  # seed 3: two dry days, one row
    with Image.open(sheet) as picture:
        assert picture.width > 6 * 100 and picture.height < picture.width
    again = runner.invoke(app, ["info", "--dataroot", dataroot, "--quiet", "--contact-sheet", str(sheet)])
    assert (again.exit_code, again.output) == (2, f"error: {sheet} exists; pass --overwrite to replace it\n")
    same = tmp_path / "same.png"
    clash = runner.invoke(app, ["info", "--dataroot", dataroot, "--quiet", "--out", str(same), "--contact-sheet",
                                str(same), "--overwrite"])
    assert (clash.exit_code, clash.output) == (2, f"error: --contact-sheet: {same} is also --out; give each its "
                                                  "own file\n")
    assert not same.exists()


def test_running_out_of_memory_is_one_error_line_with_exit_code_1():
    import torch
    import typer

    from sianms_cli.cli._app import command

    group = typer.Typer()

    @command("allocate", group)
    def allocate(elements: int) -> None:
        if elements < 0:
            raise MemoryError
        if elements == 0:
            raise RuntimeError("a bug, not memory")
        torch.empty(elements)

    @command("other", group)
    def other() -> None:  # a group of one command would run it without its name
        pass

    too_many = runner.invoke(group, ["allocate", str(10**15)])
    assert too_many.exit_code == 1
    assert too_many.stderr == "error: out of memory (you tried to allocate 4000000000000000 bytes)\n"
    python_side = runner.invoke(group, ["allocate", "--", "-1"])
    assert python_side.exit_code == 1 and python_side.stderr == "error: out of memory\n"
    bug = runner.invoke(group, ["allocate", "0"])
    assert isinstance(bug.exception, RuntimeError)  # anything else keeps its traceback


def test_a_path_that_starts_with_a_tilde_is_the_home_folders(tmp_path, monkeypatch):
    # `--dataroot=~/data`: the shell leaves the tilde as it is; a folder named `~` is never wanted.
    from pathlib import Path

    from sianms_cli.cli._app import home_expanded

    monkeypatch.setenv("HOME", str(tmp_path))
    result = runner.invoke(app, ["info", "--dataroot=~/data", "--quiet"])
    assert (result.exit_code, result.output) == (2, f"error: {tmp_path}/data/v1.0-mini: version folder not "
                                                    "found (expected <dataroot>/<version>/)\n")
    assert home_expanded([Path("~/a"), Path("b")]) == [tmp_path / "a", Path("b")]
    assert home_expanded("~/text") == "~/text"  # only paths
    unknown = runner.invoke(app, ["info", "--dataroot", "~nobody-sianms-knows/data", "--quiet"])
    assert (unknown.exit_code, unknown.output) == (
        2, "error: ~nobody-sianms-knows/data: no home folder is known for ~nobody-sianms-knows\n")


def test_a_tilde_in_a_config_file_or_after_file_colon_is_the_home_folders(tmp_path, monkeypatch):
    """--config and --detector are text options (a preset name, file:PATH): their paths had kept the tilde."""
    from sianms_cli.detection2d.detectors import parse_detector
    from sianms_cli.metrics.config import load_config

    monkeypatch.setenv("HOME", str(tmp_path))
    (tmp_path / "c.json").write_text(json.dumps({"min_recall": 0.2}))
    assert load_config("~/c.json").min_recall == 0.2
    assert parse_detector("file:~/dets.json").file == tmp_path / "dets.json"
