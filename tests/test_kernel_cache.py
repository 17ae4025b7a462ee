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


@pytest.mark.skipif(shutil.which("unshare") is None or not Path("/mnt").is_dir(),
                    reason="needs unshare and /mnt to mount the package and the temporary folders read-only")
@pytest.mark.parametrize("temporary", ["writable", "read-only"])
def test_synth_runs_with_no_writable_package_nor_home(tmp_path, temporary):
    """In a mount namespace of its own the checkout is read-only and HOME a read-only filesystem; for
    "read-only" every temporary folder Python would take is one too: the kernels compile uncached, and
    numpy still loads after the kernel settings (the executable checks)."""
    (tmp_path / "home").mkdir()
    (tmp_path / "tmp").mkdir()
    work = Path("/mnt")  # this test's folder, mounted where the read-only temporary folders do not hide it
    # Made read-only in place, not hidden: the checkout or the venv may lie in one (CI's venv is in /tmp).
    hide = "".join(f" && mount --bind {folder} {folder} && mount -o remount,bind,ro {folder}"
                   for folder in ("/tmp", "/var/tmp") if temporary == "read-only" and Path(folder).is_dir())
    script = (f"mount --make-rprivate / && mount --bind {REPO_ROOT} {REPO_ROOT} && "
              f"mount -o remount,bind,ro {REPO_ROOT} && mount --bind {tmp_path} {work} && "
              f"mount -t tmpfs -o ro,size=64k tmpfs {work / 'home'}{hide} && cd {work / 'home'} && "
              f"exec {Path(sys.executable).parent / 'sianms'} synth --out {work / 'data'} --scenes 1 "
              "--scene-seconds 1 --sensors none --quiet")
    environment = {key: value for key, value in os.environ.items()
                   if key not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME", "TMPDIR", "TEMP", "TMP")}
    environment.update(HOME=str(work / "home"), TMPDIR=str(work / ("tmp" if temporary == "writable" else "home")))
    done = subprocess.run(["unshare", "-m", "sh", "-c", script], capture_output=True, text=True, env=environment,
                          timeout=600)
    if done.returncode != 0 and "mount" in done.stderr and "sianms" not in done.stderr:
        pytest.skip(f"cannot mount here: {done.stderr.strip()}")
    assert (done.returncode, done.stderr) == (0, ""), done.stderr[-2000:]
    assert (tmp_path / "data" / "v1.0-mini" / "scene.json").is_file()
    cached = tmp_path / "tmp" / f"sianms-kernels-{os.getuid()}"
    assert any(cached.rglob("*.nbi")) if temporary == "writable" else not cached.exists()
