"""The machine facts that decide an output's last bits, recorded beside it.

The same code, seed and package versions give the same bytes only on one numeric platform:
the synthetic dataset differs between AVX-512 and AVX2 machines (numpy dispatches float64
functions to AVX-512 code there), trainings between CPU makers (MKL picks its kernels by
maker) (README, "The CI gate"). A record of both, with the versions of the packages that do
the arithmetic, tells two differing outputs apart without rerunning either.
"""

from __future__ import annotations

import platform
from importlib import metadata
from pathlib import Path

CPUINFO = Path("/proc/cpuinfo")
AVX512_FLAGS = frozenset({"avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl"})
"""What numpy's AVX512_SKX and torch's AVX512 kernels both need."""
AVX2_FLAGS = frozenset({"avx2", "fma"})
ARITHMETIC_PACKAGES = ("numpy", "numba")  # synth's: torch is not imported there


def numeric_platform(cpuinfo: str | None = None) -> dict[str, str]:
    """CPU maker, vector width (``AVX512``, ``AVX2``, ``other``; ``unknown`` without /proc/cpuinfo),
    architecture, Python and the arithmetic packages' versions.

    Args:
        cpuinfo: the text of ``/proc/cpuinfo``; read from the machine when None.
    """
    text = _read_cpuinfo() if cpuinfo is None else cpuinfo
    fields: dict[str, str] = {}
    for line in text.splitlines():
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    flags = set(fields.get("flags", "").split())
    width = ("unknown" if not flags else "AVX512" if AVX512_FLAGS <= flags else "AVX2" if AVX2_FLAGS <= flags
             else "other")
    record = {"cpu_vendor": fields.get("vendor_id", "unknown"), "vector_width": width,
              "machine": platform.machine(), "python": platform.python_version()}
    record.update({package: _version(package) for package in ARITHMETIC_PACKAGES})
    return record


def _read_cpuinfo() -> str:
    try:
        return CPUINFO.read_text(errors="replace")
    except OSError:
        return ""


def _version(package: str) -> str:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "not installed"
