"""scripts/devkit_metrics_reference.py loaded as a module (it is not in a package)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]


def _load_reference_script():
    spec = importlib.util.spec_from_file_location("devkit_metrics_reference",
                                                  REPO_ROOT / "scripts" / "devkit_metrics_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


reference_script = _load_reference_script()
