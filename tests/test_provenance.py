"""The numeric platform recorded beside outputs: CPU maker and vector width from /proc/cpuinfo,
and the kernels the arithmetic libraries run (AVX2 ones on every AVX2 CPU, sianms_cli.kernels)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from sianms_cli.kernels import AVX2_SETTINGS, NATIVE_SWITCH, cpu_facts
from sianms_cli.provenance import numeric_platform

XEON = """processor\t: 0
vendor_id\t: GenuineIntel
flags\t\t: fpu sse2 avx avx2 fma avx512f avx512dq avx512cd avx512bw avx512vl
processor\t: 1
vendor_id\t: GenuineIntel
"""
EPYC_ZEN3 = "vendor_id\t: AuthenticAMD\nflags\t\t: fpu sse2 avx avx2 fma bmi2\n"
AVX512F_ONLY = "vendor_id\t: GenuineIntel\nflags\t\t: avx2 fma avx512f\n"  # Xeon Phi: not numpy's AVX512_SKX
OLD = "vendor_id\t: GenuineIntel\nflags\t\t: sse2 sse4_2 avx\n"


@pytest.mark.parametrize("cpuinfo, vendor, width", [
    (XEON, "GenuineIntel", "AVX512"), (EPYC_ZEN3, "AuthenticAMD", "AVX2"), (AVX512F_ONLY, "GenuineIntel", "AVX2"),
    (OLD, "GenuineIntel", "other"), ("", "unknown", "unknown")])
def test_maker_and_vector_width_from_cpuinfo(cpuinfo, vendor, width):
    record = numeric_platform(cpuinfo)
    assert (record["cpu_vendor"], record["vector_width"]) == (vendor, width)
    assert set(record) == {"cpu_vendor", "vector_width", "kernels", "machine", "python", "numpy", "numba"}


def test_the_ci_names_the_platform_as_the_record_does():
    script = Path(__file__).resolve().parents[1] / ".ci" / "platform"
    path = f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"  # the script runs `python`
    printed = subprocess.run([str(script)], capture_output=True, text=True, check=True,
                             env={**os.environ, "PATH": path}).stdout.strip()
    record = numeric_platform()
    assert printed == f"{record['cpu_vendor']}.{record['kernels']}"  # this session's, pinned as `sianms` pins


def test_the_ci_names_the_native_platform_when_asked_for_native_kernels():
    script = Path(__file__).resolve().parents[1] / ".ci" / "platform"
    path = f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"
    environment = {name: value for name, value in os.environ.items() if name not in AVX2_SETTINGS}
    printed = subprocess.run([str(script)], capture_output=True, text=True, check=True,
                             env={**environment, "PATH": path, NATIVE_SWITCH: "1"}).stdout.strip()
    vendor, width = cpu_facts()
    assert printed == f"{vendor}.{width}"
