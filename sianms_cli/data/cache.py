"""Writing and reading the prepared cache: atomic, streaming shard files and the manifest.

Layout of a cache folder::

    manifest.json                      resolved config, counts and checksums of finished shards
    detections/<shard>.parquet         one zstd Parquet file per shard (= scene)
    frustums/<shard>.parquet
    pairs/<shard>.parquet
    _shards/<shard>.json               completion record of a shard (written last)
    _shards/<shard>.lock               held (flock) by the run writing the shard
    .sianms.lock                       held while a run claims the folder or rewrites the manifest

A shard's files are written under hidden temporary names (``.<shard>.parquet.<pid>.<random>.partial``),
one row group per sample, renamed when complete, and the shard counts as finished only once its
completion record (with the files' row counts and SHA-256) exists. A rerun skips finished
shards and rewrites the others; readers (which skip hidden files and match ``*.parquet``)
never see a half-written file. The manifest says ``complete`` only when every shard of the
split is finished.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from sianms_cli.data.schemas import DATASETS, SCHEMA_VERSION
from sianms_cli.errors import DataFormatError
from sianms_cli.io import PARTIAL_SUFFIX, AtomicFile, os_errors_as_output_errors, read_json, sha256_of, write_json

MANIFEST = "manifest.json"
SHARDS = "_shards"
FOLDER_LOCK = ".sianms.lock"


def shard_lock_path(root: Path, shard: str) -> Path:
    return Path(root) / SHARDS / f"{shard}.lock"


class ShardWriter:
    """Streams one shard of the three datasets to temporary files; :meth:`commit` finishes it.

    Use as a context manager: leaving the block without :meth:`commit` (an error, a full
    disk, an interrupt) closes and deletes the temporary files. Only a kill that gives no
    chance to clean up leaves them, hidden; :func:`clear_shard` removes them on the next run.
    """

    def __init__(self, root: Path, shard: str, schemas: dict[str, pa.Schema]) -> None:
        self.root, self.shard, self.schemas = Path(root), shard, schemas
        self.rows = {name: 0 for name in DATASETS}
        # The files are io.py's, not pyarrow's, so that they are closed and deleted even
        # when writing the Parquet footer fails.
        self._files: dict[str, AtomicFile] = {}
        self._writers: dict[str, pq.ParquetWriter] = {}
        try:
            for name in DATASETS:
                self._files[name] = AtomicFile(self._final(name))
                with os_errors_as_output_errors(self._final(name)):
                    self._writers[name] = pq.ParquetWriter(
                        self._files[name].stream, schemas[name], compression="zstd", write_statistics=True)
        except BaseException:
            self._abandon()
            raise

    def _final(self, name: str) -> Path:
        return self.root / name / f"{self.shard}.parquet"

    def write(self, name: str, table: pa.Table) -> None:
        """Append ``table`` (one sample's rows) as a row group of dataset ``name``."""
        if table.num_rows:
            with os_errors_as_output_errors(self._final(name)):
                self._writers[name].write_table(table.cast(self.schemas[name]))
            self.rows[name] += table.num_rows

    def _abandon(self) -> None:
        """Close what is open, ignoring errors (the files are deleted), and delete the files."""
        for writer in self._writers.values():
            try:
                writer.close()
            except OSError:
                writer.is_open = False  # else pyarrow retries the close, and fails again, when collected
        for file in self._files.values():
            file.discard()
        self._writers, self._files = {}, {}

    def commit(self, extra: dict[str, Any]) -> dict[str, Any]:
        """Finish the files, rename them into place, then write the shard's completion record."""
        files = {}
        for name in DATASETS:
            with os_errors_as_output_errors(self._final(name)):
                self._writers[name].close()
            del self._writers[name]
            self._files.pop(name).commit()
            files[f"{name}/{self.shard}.parquet"] = {
                "rows": self.rows[name], "sha256": sha256_of(self._final(name))}
        record = {"shard": self.shard, "files": files, **extra}
        write_json(self.root / SHARDS / f"{self.shard}.json", record)
        return record

    def __enter__(self) -> ShardWriter:
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if exc_type is not None:
            self._abandon()


def shard_done(root: Path, shard: str) -> bool:
    """A shard is finished when its completion record and all its files exist."""
    root = Path(root)
    return (root / SHARDS / f"{shard}.json").is_file() and all(
        (root / name / f"{shard}.parquet").is_file() for name in DATASETS)


def clear_shard(root: Path, shard: str) -> None:
    """Remove every file of an unfinished shard, temporary files of a killed run included."""
    root = Path(root)
    for name in DATASETS:
        (root / name / f"{shard}.parquet").unlink(missing_ok=True)
        for leftover in (root / name).glob(f".{shard}.parquet.*{PARTIAL_SUFFIX}"):
            leftover.unlink(missing_ok=True)
    (root / SHARDS / f"{shard}.json").unlink(missing_ok=True)


def shard_records(root: Path) -> dict[str, dict[str, Any]]:
    """The completion records of the finished shards, by shard name."""
    folder = Path(root) / SHARDS
    records = {}
    if folder.is_dir():
        for path in sorted(folder.glob("*.json")):
            shard = path.stem
            if shard_done(root, shard):
                records[shard] = json.loads(path.read_text(encoding="utf-8"))
    return records


def read_manifest(root: Path) -> dict[str, Any] | None:
    """The manifest of the cache at ``root``; None when there is none.

    A manifest that is not a sianms cache manifest raises DataFormatError naming the field.
    """
    path = Path(root) / MANIFEST
    if not path.is_file():
        return None
    manifest = read_json(path)
    if not isinstance(manifest, dict):
        raise DataFormatError(path, "not a sianms cache manifest (expected a JSON object)")
    for field, kind in (("schema_version", int), ("config", dict)):
        if not isinstance(manifest.get(field), kind):
            raise DataFormatError(path, f"not a sianms cache manifest ({kind.__name__} expected)", field=field)
    return manifest


def write_manifest(root: Path, config: dict[str, Any], expected_shards: list[str],
                   dataroot: str | Path) -> dict[str, Any]:
    """(Re)write manifest.json from the config and the finished shards' records.

    ``complete`` is true only when the split has shards and every one of them is finished.
    ``dataroot`` is recorded for people; the cache is tied to the dataset's content through
    the config's fingerprint, not to this path.
    """
    records = shard_records(root)
    totals = {name: 0 for name in DATASETS}
    samples = 0
    files = {}
    for record in records.values():
        samples += record.get("samples", 0)
        for path, info in record["files"].items():
            files[path] = info
            totals[path.split("/")[0]] += info["rows"]
    missing = [shard for shard in expected_shards if shard not in records]
    manifest = {
        "schema_version": SCHEMA_VERSION,
        "config": config,
        "shards_expected": len(expected_shards),
        "shards_finished": len([s for s in expected_shards if s in records]),
        "dataroot": str(Path(dataroot).resolve()),
        "complete": bool(expected_shards) and not missing,
        "missing_shards": missing,
        "counts": {"samples": samples, **totals},
        "files": dict(sorted(files.items())),
    }
    write_json(Path(root) / MANIFEST, manifest)
    return manifest


def read_dataset(root: Path, name: str, columns: list[str] | None = None) -> pa.Table:
    """All finished shard files of dataset ``name`` as one table (shard-name order)."""
    folder = Path(root) / name
    paths = sorted(folder.glob("*.parquet"))
    if not paths:
        raise DataFormatError(folder, f"no finished {name} shard files (*.parquet)")
    return pa.concat_tables([pq.read_table(path, columns=columns) for path in paths])


def roi_feature_shape(path: Path) -> tuple[int, ...]:
    """(C, PH, PW) of the ROI features in a detections file, from its metadata."""
    metadata = pq.read_schema(path).metadata or {}
    shape = metadata.get(b"sianms.roi_feature_shape")
    if shape is None:
        raise DataFormatError(path, "no sianms.roi_feature_shape in the schema metadata")
    return tuple(int(v) for v in shape.decode().split(","))


def decode_roi_features(column: pa.ChunkedArray | pa.Array | list[bytes], shape: tuple[int, ...]) -> np.ndarray:
    """(N, C, PH, PW) float16 features from a ``roi_feature`` column."""
    if isinstance(column, (pa.ChunkedArray, pa.Array)):
        column = column.to_pylist()
    if len(column) == 0:
        return np.zeros((0, *shape), dtype=np.float16)
    return np.frombuffer(b"".join(column), dtype="<f2").reshape(len(column), *shape)
