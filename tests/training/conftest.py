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


@pytest.fixture(scope="session")
def two_shard_dataroot(synthetic_dataroot):
    """A small dataroot of 3 mini scenes: mini_train holds two of them."""
    return synthetic_dataroot(scenes=3)


@pytest.fixture(scope="session")
def two_shard_cache(two_shard_dataroot, tmp_path_factory):
    """mini_train of :func:`two_shard_dataroot`: a cache of two shards, one per stream of two."""
    folder = tmp_path_factory.mktemp("two-shard-cache")
    return prepare(PrepareConfig(dataroot=str(two_shard_dataroot), version="v1.0-mini", split="mini_train"),
                   folder / "mini_train").out
