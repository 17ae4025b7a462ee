"""The compiled kernels need no writable package folder and no writable HOME: their cache goes to the
first writable folder of NUMBA_CACHE_DIR, the package, the user's cache folder and a private temporary
folder, or there is none. A system install run by another user had ended `synth` and `eval` in
numba's "cannot cache function" traceback."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from sianms_cli import kernel_cache
from sianms_cli.kernel_cache import is_private_folder, kernel_cache_folder

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def read_only_package(monkeypatch, read_only_folder):
    """The package's kernel folders on a read-only filesystem."""
    monkeypatch.setattr(kernel_cache, "PACKAGE", read_only_folder)
    return read_only_folder


def test_the_package_folder_serves_where_it_is_writable(tmp_path, monkeypatch):
    monkeypatch.setattr(kernel_cache, "PACKAGE", tmp_path)
    assert kernel_cache_folder({"HOME": str(tmp_path / "home")}) is None


def test_the_folders_are_taken_in_order(read_only_package, read_only_folder, tmp_path, monkeypatch):
    chosen = tmp_path / "chosen"
    assert kernel_cache_folder({"NUMBA_CACHE_DIR": str(chosen), "HOME": str(tmp_path)}) == chosen
    assert kernel_cache_folder({"NUMBA_CACHE_DIR": str(read_only_folder / "x"), "HOME": str(tmp_path)}) == \
        tmp_path / ".cache" / "sianms" / "kernels"
    assert kernel_cache_folder({"XDG_CACHE_HOME": str(tmp_path / "xdg"), "HOME": str(read_only_folder)}) == \
        tmp_path / "xdg" / "sianms" / "kernels"
    monkeypatch.setattr(kernel_cache.tempfile, "gettempdir", lambda: str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    assert kernel_cache_folder({"HOME": str(read_only_folder)}) == tmp_path / "tmp" / f"sianms-kernels-{os.getuid()}"
    monkeypatch.setattr(kernel_cache.tempfile, "gettempdir", lambda: str(read_only_folder))
    assert kernel_cache_folder({"HOME": str(read_only_folder)}) is False
    assert kernel_cache_folder({}) is False


def test_a_temporary_folder_others_can_write_to_is_not_used(tmp_path):
    """Machine code read from a folder another user can write would run as this user."""
    shared = tmp_path / "sianms-kernels"
    shared.mkdir(mode=0o777)
    shared.chmod(0o777)
    assert not is_private_folder(shared)
    shared.chmod(0o700)
    assert is_private_folder(shared)
    (tmp_path / "a-link").symlink_to(shared)
    assert not is_private_folder(tmp_path / "a-link")


@pytest.mark.skipif(shutil.which("unshare") is None, reason="needs unshare to mount the package read-only")
@pytest.mark.parametrize("temporary", ["writable", "read-only"])
def test_synth_runs_with_no_writable_package_nor_home(tmp_path, temporary):
    """In a mount namespace of its own, the checkout is read-only, HOME is a read-only filesystem, and so
    is the temporary folder for "read-only": the kernels then compile without a cache."""
    home = tmp_path / "home"
    home.mkdir()
    out = tmp_path / "data"
    script = (f"mount --make-rprivate / && mount --bind {REPO_ROOT} {REPO_ROOT} && "
              f"mount -o remount,bind,ro {REPO_ROOT} && mount -t tmpfs -o ro,size=64k tmpfs {home} && "
              f"exec {sys.executable} -m sianms_cli synth --out {out} --scenes 1 --scene-seconds 1 --sensors none "
              "--quiet")
    environment = {key: value for key, value in os.environ.items() if key not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME")}
    environment.update(HOME=str(home), TMPDIR=str(home if temporary == "read-only" else tmp_path))
    done = subprocess.run(["unshare", "-m", "sh", "-c", script], capture_output=True, text=True, env=environment,
                          timeout=600)
    if done.returncode != 0 and "mount" in done.stderr and "sianms" not in done.stderr:
        pytest.skip(f"cannot mount here: {done.stderr.strip()}")
    assert (done.returncode, done.stderr) == (0, ""), done.stderr[-2000:]
    assert (out / "v1.0-mini" / "scene.json").is_file()
    cached = tmp_path / f"sianms-kernels-{os.getuid()}"
    assert any(cached.rglob("*.nbi")) if temporary == "writable" else not cached.exists()
