"""The machine facts that decide an output's last bits, recorded beside it.

The same code, seed and package versions give the same bytes only on one numeric platform:
trainings differ between CPU makers (MKL picks its kernels by maker), and both the dataset and
the trainings between AVX-512 and AVX2 kernels, which ``sianms`` avoids by running AVX2 ones
everywhere (:mod:`sianms_cli.kernels`; docs/reproducibility.md). A record of the CPU, the kernels
in use and the versions of the packages that do the arithmetic tells two differing outputs
apart without rerunning either.
"""

from __future__ import annotations

import platform
from importlib import metadata

from sianms_cli.kernels import cpu_facts, kernels_in_use

ARITHMETIC_PACKAGES = ("numpy", "numba")  # synth's: torch is not imported there


def numeric_platform(cpuinfo: str | None = None) -> dict[str, str]:
    """CPU maker, vector width (:func:`~sianms_cli.kernels.cpu_facts`), the kernels the
    libraries run (:func:`~sianms_cli.kernels.kernels_in_use`), architecture, Python and the
    arithmetic packages' versions.

    Args:
        cpuinfo: the text of ``/proc/cpuinfo``; read from the machine when None.
    """
    vendor, width = cpu_facts(cpuinfo)
    record = {"cpu_vendor": vendor, "vector_width": width, "kernels": kernels_in_use(width),
              "machine": platform.machine(), "python": platform.python_version()}
    record.update({package: _version(package) for package in ARITHMETIC_PACKAGES})
    return record


def _version(package: str) -> str:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "not installed"
