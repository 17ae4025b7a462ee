"""`sianms synth` through the CLI: the command shape, --json, and one-line errors with exit code 2."""

import errno
import json
import os
import subprocess
import sys

import pytest
from typer.testing import CliRunner

from sianms_cli.cli import app

runner = CliRunner()
TINY = ["--scenes", "1", "--scene-seconds", "0.5", "--image-scale", "0.05", "--quiet"]


def synth(*args: str):
    return runner.invoke(app, ["synth", *args])


def assert_one_error_line(result, *fragments: str) -> None:
    assert result.exit_code == 2, result.output
    assert result.stdout == "" and result.stderr.startswith("error: ") and result.stderr.count("\n") == 1
    for fragment in fragments:
        assert fragment in result.stderr


def test_help_shows_the_command_shape():
    result = synth("-h")
    assert result.exit_code == 0
    for option in ("--out", "--overwrite", "--quiet", "--json", "--workers", "--version", "--seed"):
        assert option in result.output


def test_json_prints_the_result_and_nothing_else(tmp_path):
    result = synth("--out", str(tmp_path / "data"), *TINY, "--json")
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout) == {"out": str(tmp_path / "data"), "version": "v1.0-mini", "scenes": 1,
                                         "samples": 1}


def test_overwrite_replaces_an_earlier_output_only(tmp_path):
    out = tmp_path / "data"
    assert synth("--out", str(out), *TINY, "--sensors", "none").exit_code == 0
    result = synth("--out", str(out), *TINY)
    assert_one_error_line(result, str(out), "exists and is not empty; pass --overwrite")
    result = synth("--out", str(out), *TINY, "--overwrite")
    assert result.exit_code == 0, result.output
    assert f"wrote 1 scenes (1 samples) to {out / 'v1.0-mini'}" in result.stdout
    (out / "keep.txt").write_text("mine")
    result = synth("--out", str(out), *TINY, "--overwrite")
    assert_one_error_line(result, str(out), "'keep.txt' is not something sianms synth writes")
    assert (out / "keep.txt").read_text() == "mine"


@pytest.mark.parametrize("args, fragments", [
    (["--version", "../escape"], ["--version must be one folder name", "'../escape'"]),
    (["--workers", "0"], ["--workers must be at least 1"]),
    (["--scene-seconds", "30"], ["--scene-seconds must be in (0, 20]"]),
    (["--image-scale", "2"], ["--image-scale must be in [0.05, 1]"]),
    (["--sensors", "radar"], ["--sensors must be one of all, none"]),
], ids=["version", "workers", "scene-seconds", "image-scale", "sensors"])
def test_bad_options_end_in_one_error_line(tmp_path, args, fragments):
    assert_one_error_line(synth("--out", str(tmp_path / "data"), *TINY, *args), *fragments)
    assert list(tmp_path.iterdir()) == []


def test_an_output_that_is_a_file_ends_in_one_error_line(tmp_path):
    (tmp_path / "data").write_text("mine")
    assert_one_error_line(synth("--out", str(tmp_path / "data"), *TINY, "--overwrite"), f"{tmp_path / 'data'}: exists")
    assert [p.name for p in tmp_path.iterdir()] == ["data"]


def test_the_working_folder_is_never_replaced(tmp_path, monkeypatch):
    work = tmp_path / "work"
    work.mkdir()
    (work / "keep.txt").write_text("mine")
    monkeypatch.chdir(work)
    assert_one_error_line(synth("--out", ".", *TINY, "--overwrite"), str(work), "working folder")
    assert [p.name for p in tmp_path.iterdir()] == ["work"] and [p.name for p in work.iterdir()] == ["keep.txt"]


def test_an_os_error_ends_in_one_error_line_naming_the_path_and_cause(tmp_path, monkeypatch):
    real_open = os.open

    def open_(path, flags, mode=0o777, **kwargs):
        if str(path).endswith(".pcd.bin") or ".pcd.bin." in str(path):
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real_open(path, flags, mode, **kwargs)

    monkeypatch.setattr(os, "open", open_)
    result = synth("--out", str(tmp_path / "data"), *TINY)
    assert_one_error_line(result, f"cannot write {tmp_path / 'data' / 'samples' / 'LIDAR_TOP'}", "No space left")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_full_disk_ends_in_one_error_line_and_leaves_nothing(full_disk, workers):
    out = full_disk / "data"
    result = synth("--out", str(out), *TINY, "--scenes", "2", "--workers", workers)
    assert_one_error_line(result, f"cannot write {out}/", "No space left on device")
    assert list(full_disk.iterdir()) == []


def test_a_read_only_folder_ends_in_one_error_line(read_only_folder):
    result = synth("--out", str(read_only_folder / "data"), *TINY)
    assert_one_error_line(result, f"cannot write {read_only_folder / 'data'}: Read-only file system")


def test_the_library_is_imported_only_when_synth_runs():
    code = "import sys, sianms_cli.cli; print('sianms_cli.synth.generate' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "False"
