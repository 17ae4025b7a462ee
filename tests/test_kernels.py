"""AVX2 kernels on every x86-64 CPU that has them (sianms_cli.kernels): asked for before numpy and
torch load, never on a CPU that lacks them, never over a user's own setting."""

import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

from sianms_cli.kernels import (AVX2_SETTINGS, NATIVE_SWITCH, avx2_kernels, cpu_facts, has_native_bf16,
                                kernels_in_use, native_by_default, numpy_avx512_features, use_avx2_kernels)

XEON = "vendor_id\t: GenuineIntel\nflags\t\t: fpu sse2 avx avx2 fma avx512f avx512dq avx512cd avx512bw avx512vl\n"
EPYC_ZEN3 = "vendor_id\t: AuthenticAMD\nflags\t\t: fpu sse2 avx avx2 fma bmi2\n"
OLD = "vendor_id\t: GenuineIntel\nflags\t\t: sse2 sse4_2 avx\n"
ON_AVX2_CPU = cpu_facts()[1] in ("AVX2", "AVX512") and platform.machine() == "x86_64"


def unsettled_environment() -> dict[str, str]:
    """This environment without any kernel setting: what a shell that never ran sianms passes on."""
    return {name: value for name, value in os.environ.items() if name not in (*AVX2_SETTINGS, NATIVE_SWITCH)}


@pytest.mark.parametrize("cpuinfo", [XEON, EPYC_ZEN3])
def test_an_avx2_cpu_is_asked_for_avx2_kernels_by_every_library(cpuinfo):
    environ = {}
    assert use_avx2_kernels(environ, cpuinfo, "x86_64") == avx2_kernels()
    assert environ == avx2_kernels() and list(environ) == list(AVX2_SETTINGS)
    assert kernels_in_use(cpu_facts(cpuinfo)[1], environ) == "AVX2"


@pytest.mark.parametrize("cpuinfo, machine", [(OLD, "x86_64"), ("", "x86_64"), (XEON, "aarch64")])
def test_a_cpu_without_avx2_is_asked_for_nothing(cpuinfo, machine):
    environ = {}
    assert use_avx2_kernels(environ, cpuinfo, machine) == {} and environ == {}
    assert kernels_in_use(cpu_facts(cpuinfo)[1], environ) == cpu_facts(cpuinfo)[1]


def test_a_users_own_setting_is_kept_and_the_kernels_are_then_custom():
    environ = {"OPENBLAS_CORETYPE": "SkylakeX"}
    added = use_avx2_kernels(environ, XEON, "x86_64")
    assert "OPENBLAS_CORETYPE" not in added and environ["OPENBLAS_CORETYPE"] == "SkylakeX"
    assert kernels_in_use("AVX512", environ) == "custom"


@pytest.mark.parametrize("arguments, native", [
    (["train", "fpointnet", "--cache", "c"], True), (["train", "siamese"], True), (["demo", "--out", "train"], False),
    (["eval", "--split", "train"], False), ([], False), (["--help"], False)])
def test_only_the_trainings_run_native_kernels_by_default(arguments, native):
    assert native_by_default(arguments) is native
    environ = {}
    added = use_avx2_kernels(environ, XEON, "x86_64", native_default=native_by_default(arguments))
    assert (added == {}) is native


def test_the_switch_overrides_the_commands_default():
    environ = {NATIVE_SWITCH: "0"}
    assert use_avx2_kernels(environ, XEON, "x86_64", native_default=True) == avx2_kernels()
    environ = {NATIVE_SWITCH: "1"}
    assert use_avx2_kernels(environ, XEON, "x86_64", native_default=False) == {}


@pytest.mark.parametrize("flags, native", [("avx2 avx512f avx512_bf16", True), ("avx2 amx_bf16 amx_tile", True),
                                           ("avx2 avx512f avx512bw", False)])
def test_native_bf16_is_read_from_the_cpu_flags(flags, native):
    assert has_native_bf16(f"vendor_id\t: GenuineIntel\nflags\t\t: fpu {flags}\n") is native
    assert has_native_bf16("") is False


def test_native_kernels_on_request():
    environ = {NATIVE_SWITCH: "1"}
    assert use_avx2_kernels(environ, XEON, "x86_64") == {} and environ == {NATIVE_SWITCH: "1"}
    assert kernels_in_use("AVX512", environ) == "AVX512"


@pytest.mark.parametrize("version, names", [
    ((2, 4), "X86_V4 AVX512_ICL AVX512_SPR"), ((3, 0), "X86_V4 AVX512_ICL AVX512_SPR"),
    (None, "X86_V4 AVX512_ICL AVX512_SPR"),
    ((2, 3), "AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR"),
    ((1, 25), "AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL"),
])
def test_numpys_avx512_loops_go_by_the_names_of_its_release(version, names):
    assert numpy_avx512_features(version) == names
    if version is not None:  # None: the installed numpy's
        assert avx2_kernels(version)["NPY_DISABLE_CPU_FEATURES"] == names


@pytest.mark.skipif(not ON_AVX2_CPU, reason="an x86-64 CPU with AVX2")
def test_the_installed_numpy_loads_silently_with_every_avx512_loop_off():
    environment = unsettled_environment()
    use_avx2_kernels(environment)
    probe = ("import numpy\n"
             "core = numpy._core if hasattr(numpy, '_core') else numpy.core\n"
             "umath = core._multiarray_umath\n"
             "print(' '.join(name for name in umath.__cpu_dispatch__ if umath.__cpu_features__[name]))\n")
    done = subprocess.run([sys.executable, "-W", "error", "-c", probe], env=environment, capture_output=True,
                          text=True)
    assert done.returncode == 0 and done.stderr == ""  # a name numpy does not dispatch: a warning at every start
    assert not [name for name in done.stdout.split() if name.startswith(("AVX512", "X86_V4"))]


@pytest.mark.skipif(not ON_AVX2_CPU, reason="an x86-64 CPU with AVX2")
def test_asking_after_numpy_loaded_is_refused_not_recorded_as_done():
    environment = unsettled_environment()
    late = "import numpy\nfrom sianms_cli.kernels import use_avx2_kernels\nuse_avx2_kernels()\n"
    done = subprocess.run([sys.executable, "-c", late], env=environment, capture_output=True, text=True)
    assert done.returncode == 1
    assert done.stderr.strip().splitlines()[-1] == (
        "RuntimeError: use_avx2_kernels() must run before numpy and torch are imported; already imported: numpy")


@pytest.mark.skipif(not ON_AVX2_CPU or os.environ.get(NATIVE_SWITCH) == "1",
                    reason="an x86-64 CPU with AVX2, AVX2 kernels not turned off")
def test_this_session_runs_torchs_avx2_kernels_as_sianms_does():
    import torch

    assert torch.backends.cpu.get_cpu_capability() == "AVX2"


@pytest.mark.skipif(not ON_AVX2_CPU, reason="an x86-64 CPU with AVX2")
def test_the_sianms_executable_asks_before_numpy_and_torch_load():
    # `sianms` started with none of the settings made, its command line replaced by a probe: numpy
    # is not loaded yet when the command line starts, and torch then runs its AVX2 kernels.
    environment = unsettled_environment()
    probe = ("import sys, types\n"
             "def probe():\n"
             "    loaded = 'numpy' in sys.modules\n"
             "    import torch\n"
             "    print(torch.backends.cpu.get_cpu_capability(), loaded)\n"
             "sys.modules['sianms_cli.cli'] = types.SimpleNamespace(main=probe)\n"
             "from sianms_cli.entry import main\n"
             "main()\n")
    printed = subprocess.run([sys.executable, "-c", probe], env=environment, capture_output=True, text=True,
                             check=True).stdout.split()
    assert printed == ["AVX2", "False"]


@pytest.mark.skipif(not ON_AVX2_CPU, reason="an x86-64 CPU with AVX2")
def test_a_pytest_plugin_that_loads_numpy_first_gets_one_usage_line(tmp_path):
    # As a plugin pytest loads on its own may do (one in the GPU image did): numpy in before the conftest.
    (tmp_path / "numpy_first.py").write_text("import numpy\n")
    environment = {**unsettled_environment(), "PYTHONPATH": str(tmp_path)}
    done = subprocess.run([sys.executable, "-m", "pytest", "-p", "numpy_first", "-p", "no:cacheprovider",
                           "--collect-only", "-q", "tests/test_kernels.py"], env=environment, capture_output=True,
                          text=True, cwd=Path(__file__).parents[1])
    assert done.returncode == pytest.ExitCode.USAGE_ERROR
    assert "PYTEST_DISABLE_PLUGIN_AUTOLOAD=1 -p xdist" in done.stderr and "Traceback" not in done.stderr
