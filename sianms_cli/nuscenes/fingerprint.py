"""A dataset's identity by content: what a cache is tied to, wherever the dataset is moved.

The fingerprint is a SHA-256 over the 13 table files of ``<dataroot>/<version>/`` (name and
bytes of each, in a fixed order). Sensor files are left out: they are named by the tables,
and hashing gigabytes of JPEGs on every run would cost more than the job it guards.
``splits.json`` is left out too: adding a custom split changes no existing one (a job that
depends on a split records the split's scenes itself). A dataset copied or moved elsewhere keeps its fingerprint;
one whose annotations, poses or calibration changed gets another.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from sianms_cli.nuscenes.tables import TABLE_NAMES


def dataset_fingerprint(table_root: str | Path) -> str:
    """Hex SHA-256 of the 13 tables in the version folder ``table_root``."""
    table_root = Path(table_root)
    digest = hashlib.sha256()
    for name in (f"{table}.json" for table in TABLE_NAMES):
        digest.update(name.encode() + b"\0")
        with open(table_root / name, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
        digest.update(b"\0")
    return digest.hexdigest()
