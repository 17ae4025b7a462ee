"""Fixtures shared across the suite: synthetic dataroots made once per session, real faults.

A synthetic dataroot is generated once per distinct configuration and shared by every test
file that asks for it, so it is READ-ONLY: a test that damages a dataset copies it first.
"""

import importlib.util
import os
import signal
import subprocess
import uuid
from pathlib import Path
from types import SimpleNamespace

if os.environ.get("PYTEST_XDIST_WORKER"):
    # Under `pytest -n N` each worker gets one BLAS and OpenMP thread: on two cores, two workers of
    # torch's two threads each ran the suite in 653 s, of one thread each in 565 s. Set before numpy
    # and torch load (they read these once); the commands the tests start inherit them.
    for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_variable, "1")

import pytest  # noqa: E402

from sianms_cli.kernels import use_avx2_kernels  # noqa: E402  before numpy and torch load, as `sianms` does

try:
    use_avx2_kernels()
except RuntimeError as error:  # a plugin pytest loaded on its own imported numpy first
    raise pytest.UsageError(f"{error}. A pytest plugin loaded them: run with PYTEST_DISABLE_PLUGIN_AUTOLOAD=1 "
                            "-p xdist (the suite needs no other plugin), or SIANMS_NATIVE_KERNELS=1 to test "
                            "with this CPU's native kernels") from None

from sianms_cli.synth.generate import SynthConfig, run as run_synth

SMALL_SYNTH = dict(scenes=2, image_scale=0.1, scene_seconds=1.5, seed=3)


@pytest.fixture(scope="session")
def synthetic_dataroot(tmp_path_factory):
    """``make(**fields)``: the dataroot of ``SynthConfig(**SMALL_SYNTH | fields)``, made once.

    The default is 2 mini scenes of 3 key frames with 160x90 images: every table and
    sensor file in a few seconds.
    """
    made: dict[tuple, Path] = {}

    def make(**fields) -> Path:
        key = tuple(sorted({**SMALL_SYNTH, **fields}.items()))
        if key not in made:
            made[key] = run_synth(SynthConfig(**dict(key)), tmp_path_factory.mktemp("synth") / "data").out
        return made[key]

    return make


@pytest.fixture
def make_tiny():
    """``make(path, **fields)``: a fresh dataroot of ``SMALL_SYNTH | fields`` of the test's own."""
    return lambda path, **fields: run_synth(SynthConfig(**{**SMALL_SYNTH, **fields}), path).out


@pytest.fixture(scope="session")
def tiny_dataroot(synthetic_dataroot):
    """The session's shared small dataroot (read-only)."""
    return synthetic_dataroot()


def _mount_tmpfs(options: str) -> Path:
    """A fresh tmpfs mounted with ``options``; skips the test where mounting is not allowed."""
    where = Path(f"/tmp/sianms-test-{uuid.uuid4().hex[:8]}")
    where.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)], capture_output=True)
    if done.returncode != 0:
        where.rmdir()
        pytest.skip(f"cannot mount a tmpfs here ({done.stderr.decode().strip() or 'not root'})")
    return where


def _unmount(where: Path) -> None:
    subprocess.run(["umount", str(where)], check=True)
    where.rmdir()


@pytest.fixture
def full_disk():
    """A folder on a 256 KiB filesystem: writes past that fail with ENOSPC, as on a full disk."""
    where = _mount_tmpfs("size=256k,mode=0777")
    yield where
    _unmount(where)


@pytest.fixture
def read_only_folder():
    """A folder on a read-only filesystem (EROFS even for root, unlike chmod)."""
    where = _mount_tmpfs("ro,size=64k,mode=0777")
    yield where
    _unmount(where)


@pytest.fixture
def umask():
    """``set(mask)`` for the duration of one test."""
    previous = os.umask(0o022)
    yield os.umask
    os.umask(previous)


def _children(pid: int) -> list[int]:
    """Pids of the live processes whose parent is ``pid``."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def _workers(pid: int) -> list[int]:
    """Pids of the live worker processes ("spawn" children) of ``pid``; not its resource tracker."""
    found = []
    for child in _children(pid):
        try:
            if b"spawn_main" in Path(f"/proc/{child}/cmdline").read_bytes():
                found.append(child)
        except OSError:
            continue
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _default_sigint() -> None:
    """A shell that starts the tests in the background ignores SIGINT, and children inherit that:
    pass as ``preexec_fn`` to a command a test interrupts with SIGINT."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.fixture
def process_tree():
    """``children(pid)``, ``workers(pid)`` and ``alive(pid)`` from /proc: no worker outlives a run;
    ``default_sigint``, the ``preexec_fn`` of a command a test interrupts."""
    return SimpleNamespace(children=_children, workers=_workers, alive=_alive, default_sigint=_default_sigint)


@pytest.fixture(scope="session")
def eval_inputs(synthetic_dataroot, tmp_path_factory):
    """What `sianms eval` takes, made once (READ-ONLY): a 3-scene mini, the cache of its mini_train
    split (2 scenes), a siamese and an F-PointNets run trained briefly on it."""
    from sianms_cli.prepare.config import PrepareConfig
    from sianms_cli.prepare.job import run as prepare
    from sianms_cli.training.fpointnet import FPointNetConfig, run as train_fpointnet
    from sianms_cli.training.siamese import SiameseConfig, run as train_siamese

    data = synthetic_dataroot(scenes=3)
    folder = tmp_path_factory.mktemp("eval-inputs")
    cache = prepare(PrepareConfig(dataroot=str(data), version="v1.0-mini", split="mini_train"), folder / "cache").out
    train_siamese(SiameseConfig(cache=str(cache), epochs=1, seed=1), folder / "siamese")
    train_fpointnet(FPointNetConfig(cache=str(cache), epochs=1, num_points=64, num_object_points=32, batch_size=8,
                                    min_box_height=0, device="cpu", seed=1), folder / "fpointnet")
    return SimpleNamespace(dataroot=data, split="mini_train", cache=cache, siamese=folder / "siamese",
                           fpointnet=folder / "fpointnet")


@pytest.fixture(scope="session")
def eval_folders():
    """The hand-written `sianms eval` folders of tests/reporting/report_helpers.py (``make_eval``,
    ``edit_table``, ``parse_html``), for the report's CLI, start-up and browser tests, loaded by
    path: tests/reporting is on sys.path only when pytest collects a test there."""
    path = Path(__file__).resolve().parent / "reporting" / "report_helpers.py"
    spec = importlib.util.spec_from_file_location("report_helpers", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
