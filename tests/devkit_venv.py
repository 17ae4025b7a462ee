"""Where the opt-in devkit tests find the official nuscenes-devkit's interpreter, and the marks they carry.

The devkit pins numpy<2, so it lives in a venv of its own (``scripts/devkit_venv.sh``) and runs as
a subprocess: ``$SIANMS_DEVKIT_PYTHON``, else ``<repo>/.devkit-venv/bin/python``.
"""

import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
DEVKIT_PYTHON = Path(os.environ.get("SIANMS_DEVKIT_PYTHON") or REPO_ROOT / ".devkit-venv" / "bin" / "python")
needs_devkit = pytest.mark.skipif(not DEVKIT_PYTHON.is_file(),
                                  reason=f"nuscenes-devkit interpreter not found at {DEVKIT_PYTHON}: "
                                         "run scripts/devkit_venv.sh or set SIANMS_DEVKIT_PYTHON")
DEVKIT_MARKS = [pytest.mark.devkit, needs_devkit]  # a module's pytestmark
