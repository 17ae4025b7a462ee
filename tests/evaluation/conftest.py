"""Shared inputs of the evaluation tests.

``reference_folder`` is the dataroot and results files of scripts/devkit_metrics_reference.py
(the same function writes them for the committed devkit fixture), built once per session.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]
FIXTURE = REPO_ROOT / "tests" / "fixtures" / "metrics" / "devkit_reference.json"


def _load_reference_script():
    spec = importlib.util.spec_from_file_location("devkit_metrics_reference",
                                                  REPO_ROOT / "scripts" / "devkit_metrics_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


reference_script = _load_reference_script()
DEVKIT_PYTHON = reference_script.devkit_python()
needs_devkit = [
    pytest.mark.devkit,
    pytest.mark.skipif(not DEVKIT_PYTHON.is_file(),
                       reason=f"nuscenes-devkit interpreter not found at {DEVKIT_PYTHON}: run "
                              "scripts/devkit_venv.sh or set SIANMS_DEVKIT_PYTHON"),
]


@pytest.fixture(scope="session")
def reference_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """DIR with DIR/dataroot (synthetic v1.0-mini + racks + splits.json) and DIR/results/*.json."""
    folder = tmp_path_factory.mktemp("metrics_reference")
    reference_script.build(folder)
    return folder


@pytest.fixture(scope="session")
def reference_db(reference_folder: Path):
    from sianms_cli.nuscenes.loader import NuScenesDB

    return NuScenesDB(reference_folder / "dataroot", reference_script.VERSION)


@pytest.fixture(scope="session")
def devkit_fixture() -> dict:
    return json.loads(FIXTURE.read_text())

