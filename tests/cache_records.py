"""Record a cache's shard files as they are now, for tests that write or edit a cache on purpose.

A cache reader refuses a shard file that the manifest does not list, or that differs from what it
lists (size, rows, SHA-256). A test of what a reader does with a hand-made cache, or with an
edited value, records the files first, as if prepare had written them so.
"""

import json
from pathlib import Path

import pyarrow.parquet as pq

from sianms_cli.data.cache import MANIFEST, SHARDS
from sianms_cli.data.schemas import DATASETS, SCHEMA_VERSION
from sianms_cli.io import sha256_of


def file_entry(path: Path) -> dict:
    """What a manifest records of a shard file: rows, size and SHA-256."""
    return {"rows": pq.read_metadata(path).num_rows, "bytes": path.stat().st_size, "sha256": sha256_of(path)}


def record_again(cache: Path, config: dict | None = None) -> Path:
    """List every shard file of ``cache`` as it is now in a complete manifest (its config kept, or
    ``config``, or none), and in each shard's completion record where there is one."""
    cache = Path(cache)
    path = cache / MANIFEST
    manifest = json.loads(path.read_text()) if path.is_file() else {"schema_version": SCHEMA_VERSION}
    manifest["config"] = config if config is not None else manifest.get("config", {})
    files = {f"{dataset}/{file.name}": file_entry(file) for dataset in DATASETS if (cache / dataset).is_dir()
             for file in sorted((cache / dataset).glob("*.parquet"))}
    manifest.update(complete=True, missing_shards=[], files=files)
    path.write_text(json.dumps(manifest))
    for record_path in sorted((cache / SHARDS).glob("*.json")):
        record = json.loads(record_path.read_text())
        record["files"] = {name: files[name] for name in record["files"] if name in files}
        record_path.write_text(json.dumps(record))
    return cache
