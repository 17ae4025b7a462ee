"""`synth` under faults: permissions, OS errors and signals leave either a finished dataroot or nothing."""

import errno
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sianms_cli import io
from sianms_cli.synth.generate import SynthConfig, run

REPO_ROOT = Path(__file__).resolve().parents[2]
TINY = SynthConfig(scenes=1, scene_seconds=0.5, image_scale=0.05)  # one keyframe: 6 JPEGs and one sweep


@pytest.mark.parametrize("mask, file_mode, folder_mode", [(0o022, 0o644, 0o755), (0o077, 0o600, 0o700)],
                         ids=["umask-022", "umask-077"])
def test_files_and_folders_get_the_permissions_of_the_umask(tmp_path, umask, mask, file_mode, folder_mode):
    umask(mask)
    out = run(TINY, tmp_path / "out").out
    entries = list(out.rglob("*"))
    files = [p for p in entries if p.is_file()]
    assert {"".join(p.suffixes) for p in files} == {".jpg", ".pcd.bin", ".json", ".png"}
    assert {stat.S_IMODE(p.stat().st_mode) for p in files} == {file_mode}
    assert {stat.S_IMODE(p.stat().st_mode) for p in [out, *entries] if p.is_dir()} == {folder_mode}


def test_a_read_only_parent_ends_in_one_error_naming_it(tmp_path, monkeypatch):
    parent = tmp_path / "read-only"
    parent.mkdir()
    real_mkdir = os.mkdir

    def mkdir(path, mode=0o777, **kwargs):
        if Path(path).parent == parent:
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real_mkdir(path, mode, **kwargs)

    monkeypatch.setattr(os, "mkdir", mkdir)
    with pytest.raises(io.OutputError, match=f"cannot write {parent}/out: Permission denied"):
        run(TINY, parent / "out")
    assert list(parent.iterdir()) == []


def test_a_full_disk_while_writing_images_leaves_nothing(tmp_path, monkeypatch):
    real_open = os.open

    def open_(path, flags, mode=0o777, **kwargs):
        if "__CAM_BACK__" in str(path):
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real_open(path, flags, mode, **kwargs)

    monkeypatch.setattr(os, "open", open_)
    # The message names the file under OUT, not under the staging folder that is already gone.
    with pytest.raises(io.OutputError, match=f"cannot write {tmp_path}/out/samples/CAM_BACK/[^/]*jpg: No space left"):
        run(TINY, tmp_path / "out")
    assert list(tmp_path.iterdir()) == []


def test_a_full_disk_while_finishing_the_tables_leaves_nothing(tmp_path, monkeypatch):
    real_replace = os.replace

    def replace(source, destination, **kwargs):
        if Path(source).name.startswith(".scene.json."):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_replace(source, destination, **kwargs)

    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(io.OutputError, match=f"cannot write {tmp_path}/out/v1.0-mini/scene.json: No space left"):
        run(TINY, tmp_path / "out")
    assert list(tmp_path.iterdir()) == []


def _wait_until(condition, timeout: float = 30.0):
    deadline = time.monotonic() + timeout
    while not (value := condition()):
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)
    return value


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds the worker processes through /proc")
@pytest.mark.parametrize("signum, exit_code", [(signal.SIGTERM, 143), (signal.SIGINT, 130), (signal.SIGHUP, 129)],
                         ids=["SIGTERM", "SIGINT", "SIGHUP"])
def test_a_signal_stops_the_workers_and_leaves_nothing(tmp_path, process_tree, signum, exit_code):
    out = tmp_path / "out"
    command = [sys.executable, "-m", "sianms_cli", "synth", "--out", str(out), "--workers", "2", "--scenes", "2",
               "--image-scale", "0.05", "--quiet"]  # 20 s scenes: still sensing when the signal comes
    process = subprocess.Popen(command, cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               preexec_fn=process_tree.default_sigint)

    def workers_writing() -> list[Path]:
        assert process.poll() is None, process.communicate()[1]
        return list(tmp_path.glob(".out.*.partial/samples/*/*.jpg"))

    try:
        _wait_until(workers_writing)
        workers = process_tree.workers(process.pid)
        process.send_signal(signum)
        stdout, stderr = process.communicate(timeout=30)
    finally:
        process.kill()
        process.wait()
    assert process.returncode == exit_code, stderr
    assert stderr.startswith("interrupted") and stderr.count("\n") == 1 and stdout == ""
    assert list(tmp_path.iterdir()) == []  # no staging folder, no OUT
    assert len(workers) == 2
    _wait_until(lambda: not any(process_tree.alive(pid) for pid in workers), timeout=5.0)
