"""scripts/devkit_metrics_reference.py loaded as a module (it is not in a package), and the
marker for tests that need the devkit's interpreter."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]


def _load_reference_script():
    spec = importlib.util.spec_from_file_location("devkit_metrics_reference",
                                                  REPO_ROOT / "scripts" / "devkit_metrics_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


reference_script = _load_reference_script()
DEVKIT_PYTHON = reference_script.devkit_python()
needs_devkit = pytest.mark.skipif(
    not DEVKIT_PYTHON.is_file(),
    reason=f"nuscenes-devkit interpreter not found at {DEVKIT_PYTHON}: run scripts/devkit_venv.sh "
           "or set SIANMS_DEVKIT_PYTHON",
)
