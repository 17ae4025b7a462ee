"""Which vector kernels the arithmetic libraries run: AVX2 ones on every x86-64 CPU that has
AVX2, so a seed gives the same bytes on AVX2 and AVX-512 machines.

Each library picks its kernels by the CPU when it loads, and its AVX-512 kernels round otherwise
than its AVX2 ones: OpenBLAS's decide the dataset (numpy's matrix products in
``calibrated_sensor``), MKL's the siamese network, ATen's and numpy's own loops Frustum
PointNets; under every setting of :func:`avx2_kernels` an AVX-512 and an AVX2-only machine write
the same bytes (docs/reproducibility.md). oneDNN's setting is kept because torch may hand CPU
convolutions to oneDNN, which picks kernels by the CPU too. The settings are read once, when
each library loads, so :func:`use_avx2_kernels` runs before numpy and torch are imported: first
thing in the ``sianms`` executable, whose worker processes and torchrun ranks inherit them.

The CPU maker still matters: MKL picks kernels by maker, and its reproducible mode
(``MKL_CBWR``) is documented for Intel CPUs only.

The trainings are the exception (:func:`native_by_default`): ``sianms train`` runs each
library's own kernels unless :data:`NATIVE_SWITCH` is 0. Under AVX2 kernels the CPU's
AVX-512 and bfloat16 instructions go unused, and a training pays for it in every step, while
its weights differ across machines anyway once it runs in bfloat16 (costs measured by
``bench/train_fpointnet.py``, docs/reproducibility.md). Everything that decides a dataset, a
cache, an evaluation or the demo's CI gate keeps the AVX2 kernels.

Stdlib only: this module is imported before numpy.
"""

from __future__ import annotations

import importlib.util
import os
import platform
import re
import sys
from pathlib import Path
from typing import MutableMapping

CPUINFO = Path("/proc/cpuinfo")
AVX512_FLAGS = frozenset({"avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl"})
"""What numpy's AVX512_SKX and torch's AVX512 kernels both need."""
AVX2_FLAGS = frozenset({"avx2", "fma"})
AVX2_SETTINGS = ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES", "ATEN_CPU_CAPABILITY", "ONEDNN_MAX_CPU_ISA",
                 "MKL_ENABLE_INSTRUCTIONS")
"""The environment variables :func:`avx2_kernels` sets."""
NATIVE_SWITCH = "SIANMS_NATIVE_KERNELS"
"""1: every library picks its kernels by the CPU (faster where AVX-512 pays; other bytes); 0: AVX2
kernels, for the trainings too; unset: :func:`native_by_default` decides by the command."""
NATIVE_BY_DEFAULT = (("train",),)
"""Commands (leading words of the command line) that run native kernels unless told otherwise."""
BF16_FLAGS = frozenset({"avx512_bf16", "amx_bf16"})
"""CPU flags of native bfloat16 matrix arithmetic (AVX512-BF16 dot products, AMX tiles)."""


def cpu_facts(cpuinfo: str | None = None) -> tuple[str, str]:
    """(CPU maker, vector width): ``AVX512``, ``AVX2``, ``other``, or ``unknown`` without /proc/cpuinfo.

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
    return fields.get("vendor_id", "unknown"), width


def avx2_kernels(numpy_version: tuple[int, int] | None = None) -> dict[str, str]:
    """The settings that ask each library for its AVX2 kernels (:data:`AVX2_SETTINGS`), numpy's
    for the numpy installed (or of ``numpy_version``)."""
    return {
        "OPENBLAS_CORETYPE": "Haswell",  # OpenBLAS's AVX2 kernels (its Zen kernels are the same ones)
        "NPY_DISABLE_CPU_FEATURES": numpy_avx512_features(numpy_version or installed_numpy_version()),
        "ATEN_CPU_CAPABILITY": "avx2",
        "ONEDNN_MAX_CPU_ISA": "AVX2",
        "MKL_ENABLE_INSTRUCTIONS": "AVX2",
    }


def numpy_avx512_features(version: tuple[int, int] | None) -> str:
    """The names under which a numpy release dispatches its AVX-512 loops, all of which must be
    disabled (disabling one leaves the others on). A name a release does not dispatch makes it
    warn at every import, and the names changed: 2.4 groups the older ones as X86_V4, 2.3 added
    AVX512_SPR (checked on 1.25, 1.26, 2.0, 2.2, 2.3, 2.4 and 2.5). Unknown: the newest names."""
    if version is None or version >= (2, 4):
        return "X86_V4 AVX512_ICL AVX512_SPR"
    older = "AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL"
    return older + " AVX512_SPR" if version >= (2, 3) else older


def installed_numpy_version() -> tuple[int, int] | None:
    """(major, minor) of the numpy this interpreter would import, read from its dist-info folder's
    name without importing it (importlib.metadata would add 25 ms to every start); None if none."""
    spec = importlib.util.find_spec("numpy")
    if spec is None or not spec.submodule_search_locations:
        return None
    site = Path(next(iter(spec.submodule_search_locations))).parent
    for entry in site.glob("numpy-*-info"):  # dist-info, or egg-info
        match = re.match(r"numpy-(\d+)\.(\d+)", entry.name)
        if match:
            return int(match[1]), int(match[2])
    return None


def native_by_default(arguments: list[str]) -> bool:
    """Whether the command of ``arguments`` (the command line after the program name) runs the
    CPU's native kernels when :data:`NATIVE_SWITCH` is unset: the trainings (module docstring)."""
    words = [word for word in arguments if not word.startswith("-")]
    return any(tuple(words[:len(command)]) == command for command in NATIVE_BY_DEFAULT)


def has_native_bf16(cpuinfo: str | None = None) -> bool:
    """Whether the CPU computes bfloat16 matrix products in hardware (:data:`BF16_FLAGS`)."""
    text = _read_cpuinfo() if cpuinfo is None else cpuinfo
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip() == "flags":
            return bool(BF16_FLAGS & set(value.split()))
    return False


def use_avx2_kernels(environ: MutableMapping[str, str] = os.environ, cpuinfo: str | None = None,
                     machine: str | None = None, native_default: bool = False) -> dict[str, str]:
    """Ask every arithmetic library for its AVX2 kernels, on an x86-64 CPU that has AVX2 and FMA.

    A setting the user made is kept; :data:`NATIVE_SWITCH` set to 1 asks for none, set to 0 asks
    for them even where ``native_default`` (the command's default, :func:`native_by_default`)
    would not; on another CPU nothing is asked (AVX2 kernels would not run there). Returns what
    it set.

    Raises RuntimeError when it would set this process's environment after numpy or torch has
    loaded: they would keep the kernels they chose, while the record said AVX2.
    """
    machine = platform.machine() if machine is None else machine
    native = environ.get(NATIVE_SWITCH, "1" if native_default else "0") == "1"
    if native or machine not in ("x86_64", "AMD64"):
        return {}
    if cpu_facts(cpuinfo)[1] not in ("AVX2", "AVX512"):
        return {}
    added = {name: value for name, value in avx2_kernels().items() if name not in environ}
    loaded = [module for module in ("numpy", "torch") if module in sys.modules]
    if added and loaded and environ is os.environ:
        raise RuntimeError(f"use_avx2_kernels() must run before numpy and torch are imported; already "
                           f"imported: {', '.join(loaded)}")
    environ.update(added)
    return added


def kernels_in_use(width: str, environ: MutableMapping[str, str] = os.environ) -> str:
    """The kernels a CPU of vector ``width`` runs under ``environ``: ``AVX2`` where every setting
    of :func:`avx2_kernels` holds, the CPU's own width where none is made, else ``custom``."""
    made = [environ.get(name) == value for name, value in avx2_kernels().items()]
    if all(made) and width in ("AVX2", "AVX512"):
        return "AVX2"
    if not any(name in environ for name in AVX2_SETTINGS):
        return width
    return "custom"


def _read_cpuinfo() -> str:
    try:
        return CPUINFO.read_text(errors="replace")
    except OSError:
        return ""
