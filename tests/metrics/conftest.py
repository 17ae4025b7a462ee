"""Shared inputs of the evaluation tests.

``reference_folder`` holds the dataroot and results files that scripts/devkit_metrics_reference.py
writes (the same functions made the inputs of the committed devkit fixture), built once per
session in well under a second.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from metrics_reference import reference_script


@pytest.fixture(scope="session")
def reference_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """DIR with DIR/dataroot (v1.0-mini tables, bicycle racks, splits.json) and DIR/results/*.json."""
    folder = tmp_path_factory.mktemp("metrics_reference")
    reference_script.build(folder)
    return folder


@pytest.fixture(scope="session")
def reference_db(reference_folder: Path):
    from sianms_cli.nuscenes.loader import NuScenesDB

    return NuScenesDB(reference_folder / "dataroot", reference_script.VERSION)


@pytest.fixture(scope="session")
def devkit_fixture() -> dict:
    return json.loads(reference_script.FIXTURE.read_text())
