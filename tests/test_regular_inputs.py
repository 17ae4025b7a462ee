"""Every input that must be a regular file is checked as one, and a record sianms writes is bounded in
size: a FIFO given as a report's run or --baseline had waited for ever, /dev/zero had been read until
memory ran out."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from sianms_cli.detection2d.backbones import ResNet50C4
from sianms_cli.detection2d.external import _read_columns
from sianms_cli.errors import DataFormatError
from sianms_cli.io import read_json
from sianms_cli.reporting import report
from sianms_cli.training.run import load_checkpoint


@pytest.fixture
def fifo(tmp_path):
    path = tmp_path / "pipe.json"
    os.mkfifo(path)
    return path


def sianms(*arguments):
    """`sianms ARGUMENTS` in a process of its own, ended after a minute (a hang fails the test, not the suite)."""
    return subprocess.run([sys.executable, "-m", "sianms_cli", *map(str, arguments)], capture_output=True, text=True,
                          timeout=60)


@pytest.mark.parametrize("where", ["run", "baseline"])
@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_a_report_refuses_a_pipe_or_a_device_as_input(eval_folders, tmp_path, fifo, where, kind):
    evaluation = eval_folders.make_eval(tmp_path / "eval")
    source = fifo if kind == "fifo" else "/dev/zero"
    arguments = ([evaluation, source, "--out", tmp_path / "runs"] if where == "run"
                 else [evaluation, "--baseline", source, "--out", tmp_path / "report"])
    done = sianms("report", *arguments, "--quiet")
    what = "a pipe (FIFO)" if kind == "fifo" else "a device"
    assert (done.returncode, done.stderr) == (2, f"error: {source}: {what}, not a regular file: give a file\n")
    assert sorted(path.name for path in tmp_path.iterdir()) == ["eval", "pipe.json"]


def test_a_record_larger_than_its_format_needs_is_refused(eval_folders, tmp_path, monkeypatch):
    baseline = tmp_path / "report.json"
    baseline.write_text('{"schema": "x", "padding": "' + "x" * 5000 + '"}')
    monkeypatch.setattr(report, "RECORD_MAX_BYTES", 4096)
    with pytest.raises(DataFormatError) as raised:
        report.read_baseline(baseline)
    assert str(raised.value) == (f"{baseline}: {baseline.stat().st_size:,} bytes, more than the 4,096 such a file "
                                 "can need: not the file meant?")


@pytest.mark.parametrize("read, name", [
    (lambda path: load_checkpoint(path), "checkpoint"),
    (lambda path: ResNet50C4.from_checkpoint(path), "weights"),
    (lambda path: _read_columns(Path(path)), "detections"),
    (lambda path: read_json(path), "json"),
])
def test_checkpoints_weights_detections_and_json_refuse_what_is_not_a_regular_file(fifo, read, name):
    with pytest.raises(DataFormatError) as raised:
        read(fifo)
    assert str(raised.value) == f"{fifo}: a pipe (FIFO), not a regular file: give a file"
    with pytest.raises(DataFormatError, match="a device, not a regular file"):
        read("/dev/zero")


def test_a_folder_given_as_a_json_file_is_named_so(tmp_path):
    with pytest.raises(DataFormatError) as raised:
        read_json(tmp_path)
    assert str(raised.value) == f"{tmp_path}: a folder, not a regular file: give a file"
