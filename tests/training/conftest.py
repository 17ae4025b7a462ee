"""Caches of the session's small synthetic dataroot, prepared once and shared (READ-ONLY)."""

import pytest

from sianms_cli.prepare.config import PrepareConfig
from sianms_cli.prepare.job import run as prepare


@pytest.fixture(scope="session")
def tiny_caches(synthetic_dataroot, tmp_path_factory):
    """(train cache, val cache): mini_train and mini_val of the default small dataroot."""
    root = synthetic_dataroot()
    folder = tmp_path_factory.mktemp("siamese-caches")
    return tuple(prepare(PrepareConfig(dataroot=str(root), version="v1.0-mini", split=split), folder / split).out
                 for split in ("mini_train", "mini_val"))
