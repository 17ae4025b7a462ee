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
completion record (with the files' row counts, sizes and SHA-256) exists and every file still
has the recorded size. A rerun skips finished shards and rewrites the others; readers (which
skip hidden files and match ``*.parquet``) never see a half-written file. The manifest says
``complete`` only when every shard of the split is finished.

A shard file damaged after it was written (truncated by a full disk or a partial copy) is
read through :func:`read_shard_table`, which turns Arrow's error into a DataFormatError
naming the file.
"""

from __future__ import annotations

import errno
import hashlib
import json
import math
import os
import stat
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from sianms_cli.data.schemas import DATASETS, SCHEMA_VERSION, cache_schemas
from sianms_cli.errors import DataFormatError, quote
from sianms_cli.io import (PARTIAL_SUFFIX, AtomicFile, os_errors_as_output_errors, read_json, real_path, sha256_of,
                           write_json)

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
            final = self._final(name)
            files[f"{name}/{self.shard}.parquet"] = {
                "rows": self.rows[name], "bytes": final.stat().st_size, "sha256": sha256_of(final)}
        record = {"shard": self.shard, "files": files, **extra}
        write_json(self.root / SHARDS / f"{self.shard}.json", record)
        return record

    def __enter__(self) -> ShardWriter:
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if exc_type is not None:
            self._abandon()


def finished_record(root: Path, shard: str) -> dict[str, Any] | None:
    """The completion record of a finished shard; None when the shard is not finished.

    Finished: the record is readable and every file of the shard exists with the size the
    record gives. Sizes, not SHA-256: hashing a 100 GB cache on every rerun would cost about
    as much as preparing it, and a truncated or partly copied file changes its size. Records
    written before sizes were recorded give none; their files must have a readable Parquet
    footer instead (a truncated file loses it).
    """
    root = Path(root)
    try:
        record = json.loads((root / SHARDS / f"{shard}.json").read_text(encoding="utf-8"))
    except (FileNotFoundError, ValueError):  # absent, or not JSON: the shard is redone
        return None
    if not _is_shard_record(record, shard):  # edited or damaged: the shard is redone
        return None
    files = record["files"]
    for name in DATASETS:
        path = root / name / f"{shard}.parquet"
        if not path.is_file():
            return None
        size = (files.get(f"{name}/{shard}.parquet") or {}).get("bytes")
        intact = path.stat().st_size == size if size is not None else _has_footer(path)
        if not intact:
            return None
    return record


def _is_count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _is_shard_record(record: Any, shard: str) -> bool:
    """Whether a completion record has the form the manifest is summed from: a sample count, and
    for exactly the shard's files a row count each (and a size, where recorded)."""
    files = record.get("files") if isinstance(record, dict) else None
    if not (isinstance(files, dict) and set(files) == {f"{name}/{shard}.parquet" for name in DATASETS}):
        return False
    return _is_count(record.get("samples", 0)) and all(
        isinstance(info, dict) and _is_count(info.get("rows"))
        and (info.get("bytes") is None or _is_count(info["bytes"])) for info in files.values())


def _has_footer(path: Path) -> bool:
    """Whether ``path`` ends in a readable Parquet footer (a few kB read, not the file)."""
    try:
        pq.read_metadata(path)
    except (pa.ArrowException, OSError):
        return False
    return True


def shard_done(root: Path, shard: str) -> bool:
    """Whether a shard is finished (:func:`finished_record`)."""
    return finished_record(root, shard) is not None


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
            record = finished_record(root, path.stem)
            if record is not None:
                records[path.stem] = record
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
        "dataroot": str(real_path(dataroot)),
        "complete": bool(expected_shards) and not missing,
        "missing_shards": missing,
        "counts": {"samples": samples, **totals},
        "files": dict(sorted(files.items())),
    }
    write_json(Path(root) / MANIFEST, manifest)
    return manifest


def complete_manifest(cache: str | Path) -> dict[str, Any]:
    """The manifest of a cache a command reads, checked to be a `sianms prepare` cache that is complete.

    A cache whose prepare was interrupted holds only some of its split's shards; reading it
    would silently use part of the data.
    """
    path = Path(cache) / MANIFEST
    if Path(cache).is_file():
        raise DataFormatError(cache, "is a file: a cache is the folder `sianms prepare` wrote")
    manifest = read_manifest(Path(cache))
    if manifest is None:
        raise DataFormatError(path, "not found: not a `sianms prepare` cache (run `sianms prepare` first)")
    if not isinstance(manifest.get("complete"), bool):  # JSON 1 or "yes" is no answer
        raise DataFormatError(path, f"must be true or false, got {json.dumps(manifest.get('complete'))}; "
                                    "rerun `sianms prepare` with the same flags to rewrite it", field="complete")
    if not manifest["complete"]:
        missing = manifest.get("missing_shards")
        expected = manifest.get("shards_expected")
        count = f"{len(missing)} of {expected}" if isinstance(missing, list) and isinstance(expected, int) else "some"
        raise DataFormatError(path, f"the cache is not complete ({count} shards missing); rerun `sianms prepare` "
                                    "with the same flags to finish it", field="complete")
    return manifest


def cache_fingerprint(manifest: dict[str, Any]) -> str:
    """Hex SHA-256 of a cache's content as its manifest states it: the config (with the dataset's
    fingerprint), the counts and every file's checksum, not the path of the dataroot it was
    prepared from, so the same cache prepared or moved elsewhere keeps its fingerprint."""
    content = {key: value for key, value in manifest.items() if key != "dataroot"}
    return hashlib.sha256(json.dumps(content, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


PREPARE_AGAIN = "rerun `sianms prepare` on the cache to rebuild it"


@contextmanager
def reading_shard(path: Path, remedy: str = PREPARE_AGAIN) -> Iterator[None]:
    """Turn Arrow's error on a damaged Parquet file (truncated, overwritten) into a DataFormatError
    naming it and ``remedy``; one it cannot open or find is named in the command's OS-error line."""
    try:
        yield
    except (FileNotFoundError, PermissionError) as error:
        if error.filename is not None:
            raise
        code = error.errno or (errno.EACCES if isinstance(error, PermissionError) else errno.ENOENT)
        raise type(error)(code, os.strerror(code), str(path)) from None  # Arrow's own names no file
    except (pa.ArrowException, OSError):  # Arrow reports a bad footer or page header as either
        raise DataFormatError(path, f"not a readable Parquet file; {remedy}") from None


def read_shard_table(path: Path, columns: list[str] | None = None, filters: list | None = None) -> pa.Table:
    """``pq.read_table`` of one cache shard file; a damaged file, or a column of a detections,
    frustums or pairs shard missing or of another type than prepare writes, raises
    DataFormatError naming it (an edited column had ended in a traceback in training)."""
    with reading_shard(path):
        schema = pq.read_schema(path)
        _check_columns(path, schema, columns or schema.names)
        return pq.read_table(path, columns=columns, filters=filters)


def _check_columns(path: Path, schema: pa.Schema, columns: list[str]) -> None:
    expected = COLUMN_TYPES.get(Path(path).parent.name, {})
    for name in columns:
        index = schema.get_field_index(name)
        if index < 0:
            raise DataFormatError(path, f"no such column; {PREPARE_AGAIN}", field=name)
        kind = schema.field(index).type
        wanted = expected.get(name)
        if wanted is not None and _kind(kind) != _kind(wanted):
            raise DataFormatError(path, f"{kind} where prepare writes {wanted}; {PREPARE_AGAIN}", field=name)


def _kind(data_type: pa.DataType) -> str:
    """What readers rely on of a column's type: a number (of any width), text, a list of a kind, bytes
    (``roi_feature``'s width is the feature shape's, checked where it is decoded)."""
    if pa.types.is_integer(data_type) or pa.types.is_floating(data_type):
        return "number"
    if pa.types.is_string(data_type) or pa.types.is_large_string(data_type):
        return "text"
    if pa.types.is_binary(data_type) or pa.types.is_large_binary(data_type) or \
            pa.types.is_fixed_size_binary(data_type):
        return "bytes"
    if pa.types.is_list(data_type) or pa.types.is_large_list(data_type) or pa.types.is_fixed_size_list(data_type):
        return f"list of {_kind(data_type.value_type)}"
    return str(data_type)


COLUMN_TYPES = {dataset: {field.name: field.type for field in schema}
                for dataset, schema in cache_schemas((1, 1, 1), "").items()}
"""The type of each column prepare writes, by dataset folder."""


def require_finite(path: Path, table: pa.Table, columns: list[str]) -> None:
    """Raise DataFormatError naming the first record (``detection_id``) and field of ``table`` that
    holds a NaN or an infinity in one of ``columns`` (a list column element by element; nulls pass).

    Our own writers never store one; a hand-edited or damaged cache would otherwise surface later
    as a NaN box blamed on the file it ended up in."""
    for column in columns:
        values = table[column].combine_chunks()
        rows = None
        if pa.types.is_list(values.type):
            rows = pc.list_parent_indices(values).to_numpy()
            values = pc.list_flatten(values)
        bad = np.flatnonzero(~pc.is_finite(values).fill_null(True).to_numpy(zero_copy_only=False))
        if len(bad):
            row = bad[0] if rows is None else rows[bad[0]]
            raise DataFormatError(path, "not a finite number; rerun `sianms prepare` on the cache to rebuild it",
                                  token=str(table["detection_id"][int(row)]), field=column)


def read_dataset(root: Path, name: str, columns: list[str] | None = None) -> pa.Table:
    """All shard files of dataset ``name`` as one table (shard-name order), checked (:func:`verified_shards`)."""
    return pa.concat_tables([read_shard_table(path, columns=columns) for path in verified_shards(root, name)])


# --------------------------------------------------------------------------- the manifest enforced

UNIQUE_IDS = {"detections": "detection_id", "frustums": "detection_id"}
"""The column whose values are unique in a shard file, by dataset (pairs rows have no id)."""

_CHECKED_CACHES: dict[tuple, dict[str, Any]] = {}  # (real path, manifest identity): its manifest, checked
_CHECKED_FILES: set[tuple] = set()  # (file identity, recorded entry) of every shard file checked in this process


def verified_shards(cache: str | Path, dataset: str) -> list[Path]:
    """The shard files of ``dataset`` (detections, frustums, pairs) that the cache's manifest lists, in
    shard-name order, once the folder has been checked against the manifest (:func:`verify_cache`):
    the only way readers get shard paths, so every command refuses what another refuses."""
    cache = Path(cache)
    manifest = verify_cache(cache, (dataset,))
    paths = [cache / name for name in sorted(manifest["files"]) if name.split("/")[0] == dataset]
    if not paths:
        raise DataFormatError(cache / dataset, f"no {dataset} shard files: the cache's manifest lists none")
    return paths


def verified_shard(cache: str | Path, dataset: str, shard: str) -> Path:
    """The file of one shard of ``dataset`` (``<dataset>/<shard>.parquet``), checked as :func:`verified_shards`'."""
    cache = Path(cache)
    name = f"{dataset}/{shard}.parquet"
    files = verify_cache(cache, ())["files"]
    if name not in files:
        raise DataFormatError(cache / name, f"not listed in {MANIFEST}: the cache has no such shard; {PREPARE_AGAIN}")
    check_shard_file(cache / name, files[name])
    return cache / name


def verify_cache(cache: str | Path, datasets: tuple[str, ...] = DATASETS) -> dict[str, Any]:
    """The manifest of a complete cache (:func:`complete_manifest`), once the folder is checked against it.

    Every file the manifest lists must be there, a regular file of the recorded size; nothing else
    may be in the shard folders but hidden files (a stray or copied-in shard would be trained on,
    or scored, while the cache's fingerprint stays the same). The files of ``datasets`` must also
    have the recorded row count and SHA-256, with unique ids where the schema has them
    (:data:`UNIQUE_IDS`): :func:`check_shard_file`, which the readers of the other datasets run on
    theirs (:func:`verified_shards`). The first difference raises one DataFormatError naming the
    file and what differs.

    Hashing reads every byte once, so each file is checked once per process, and a cache's listing
    once: a training's epochs and an evaluation's scenes reuse the result. A manifest or a file
    replaced since (another identity) is checked again.
    """
    cache = Path(cache)
    try:
        key = (str(real_path(cache)), _identity(cache / MANIFEST))
    except OSError:  # no manifest: complete_manifest says so
        key = None
    if key is not None and key in _CHECKED_CACHES:
        manifest = _CHECKED_CACHES[key]
    else:
        manifest = complete_manifest(cache)
        listed = _listed_files(cache, manifest)
        _refuse_unlisted(cache, listed)
        for name, entry in listed.items():
            check_shard_size(cache / name, entry)
        if key is not None:
            _CHECKED_CACHES[key] = manifest
    for name, entry in manifest["files"].items():
        if name.split("/")[0] in datasets:
            check_shard_file(cache / name, entry)
    return manifest


def checked_files() -> set[tuple]:
    """What this process has checked (:func:`verify_cache`), for worker processes to start from
    (:func:`trust_checked_files`): the parent checked the cache, a worker need not read it all again."""
    return set(_CHECKED_FILES)


def trust_checked_files(checked: set[tuple]) -> None:
    """Take the parent's :func:`checked_files` as checked here too (a file changed since has another identity)."""
    _CHECKED_FILES.update(checked)


def _identity(path: Path) -> tuple[int, ...]:
    """What changes when a file is replaced or edited: device, inode, size and modification time."""
    stat = path.stat()
    return stat.st_dev, stat.st_ino, stat.st_size, stat.st_mtime_ns


def _listed_files(cache: Path, manifest: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The manifest's ``files``, each checked to be a shard file name with a row count and a SHA-256 (every
    sianms manifest records both; the size may be missing from an early one, whose SHA-256 covers it)."""
    where = cache / MANIFEST
    files = manifest.get("files")
    if not isinstance(files, dict):
        raise DataFormatError(where, f"expected an object of shard files, got {type(files).__name__}; "
                                     f"{PREPARE_AGAIN}", field="files")
    for name, entry in files.items():
        dataset, _, file_name = name.partition("/")
        if dataset not in DATASETS or "/" in file_name or not file_name.endswith(".parquet") or \
                file_name.startswith("."):
            raise DataFormatError(where, f"{quote(name)} is not a shard file of a cache; {PREPARE_AGAIN}",
                                  field="files")
        if not (isinstance(entry, dict) and _is_count(entry.get("rows"))
                and (entry.get("bytes") is None or _is_count(entry["bytes"]))
                and isinstance(entry.get("sha256"), str) and len(entry["sha256"]) == 64):
            raise DataFormatError(where, f"expected rows, bytes and sha256 of the file; {PREPARE_AGAIN}",
                                  field=f"files.{name}")
    return files


def _refuse_unlisted(cache: Path, listed: dict[str, Any]) -> None:
    """Refuse an entry of a shard folder that the manifest does not list (hidden ones aside: a killed
    write's temporary file, a desktop's index)."""
    for dataset in DATASETS:
        folder = cache / dataset
        if not folder.is_dir():
            continue
        for entry in sorted(folder.iterdir()):
            if not entry.name.startswith(".") and f"{dataset}/{entry.name}" not in listed:
                raise DataFormatError(entry, f"not listed in {MANIFEST}: the cache holds a file prepare did not "
                                             f"write there (copied in?); remove it, or {PREPARE_AGAIN}")


def check_shard_size(path: Path, entry: dict[str, Any]) -> os.stat_result:
    """Refuse a shard file that is missing, not a regular file, or of another size than its manifest ``entry``."""
    try:
        status = path.stat()
    except FileNotFoundError:
        raise DataFormatError(path, f"missing: {MANIFEST} lists it; {PREPARE_AGAIN}") from None
    if not stat.S_ISREG(status.st_mode):
        raise DataFormatError(path, f"not a regular file; {PREPARE_AGAIN}")
    if entry.get("bytes") is not None and status.st_size != entry["bytes"]:
        raise DataFormatError(path, f"{status.st_size:,} bytes where {MANIFEST} records {entry['bytes']:,} (cut "
                                    f"short or altered); {PREPARE_AGAIN}")
    return status


def check_shard_file(path: Path, entry: dict[str, Any]) -> None:
    """Refuse a shard file that differs from its manifest ``entry``: missing, not a regular file, another
    size (:func:`check_shard_size`), row count or SHA-256, or an id twice (:data:`UNIQUE_IDS`). Checked
    once per process and file."""
    status = check_shard_size(path, entry)
    key = ((status.st_dev, status.st_ino, status.st_size, status.st_mtime_ns), entry["rows"], entry["sha256"])
    if key in _CHECKED_FILES:
        return
    if sha256_of(path) != entry["sha256"]:
        raise DataFormatError(path, f"its content is not what {MANIFEST} records (another SHA-256: altered or "
                                    f"replaced); {PREPARE_AGAIN}")
    with reading_shard(path):
        rows = pq.read_metadata(path).num_rows
    if rows != entry["rows"]:
        raise DataFormatError(path, f"{rows:,} rows where {MANIFEST} records {entry['rows']:,}; {PREPARE_AGAIN}")
    id_column = UNIQUE_IDS.get(path.parent.name)
    if id_column is not None:
        require_unique(path, read_shard_table(path, columns=[id_column])[id_column], id_column)
    _CHECKED_FILES.add(key)


def require_unique(path: Path, ids: pa.ChunkedArray, field: str) -> None:
    """Raise DataFormatError naming the first id that ``ids`` holds more than once."""
    if pc.count_distinct(ids, mode="all").as_py() == len(ids):
        return
    counts = pc.value_counts(ids)
    repeated = counts.filter(pc.greater(counts.field("counts"), 1))
    raise DataFormatError(path, f"appears {repeated[0]['counts'].as_py()} times; an id is unique in a shard; "
                                f"{PREPARE_AGAIN}", token=str(repeated[0]["values"].as_py()), field=field)


def roi_feature_shape(path: Path) -> tuple[int, int, int]:
    """(C, PH, PW) of the ROI features in a detections file, from its metadata."""
    with reading_shard(path):
        metadata = pq.read_schema(path).metadata or {}
    shape = metadata.get(b"sianms.roi_feature_shape")
    if shape is None:
        raise DataFormatError(path, "no sianms.roi_feature_shape in the schema metadata")
    text = shape.decode(errors="replace")
    sizes = text.split(",")
    if len(sizes) != 3 or not all(size.isdecimal() and 1 <= int(size) <= MAX_ROI_FEATURE_SIZE for size in sizes):
        raise DataFormatError(path, f"sianms.roi_feature_shape must be 'C,PH,PW', three whole numbers in "
                                    f"[1, {MAX_ROI_FEATURE_SIZE:,}], got '{text}'; {PREPARE_AGAIN}")
    channels, height, width = (int(size) for size in sizes)
    return channels, height, width


MAX_ROI_FEATURE_SIZE = 2**16  # past any backbone's channels or pooled size: an edited shape is refused


def decode_roi_features(column: pa.ChunkedArray | pa.Array | list[bytes], shape: tuple[int, ...],
                        path: Path) -> np.ndarray:
    """(N, C, PH, PW) float16 features from a ``roi_feature`` column of the detections file(s) at
    ``path``; a feature whose size is not the shape's raises DataFormatError naming them."""
    if not isinstance(column, (pa.ChunkedArray, pa.Array)):
        column = pa.array(column, pa.binary())
    if len(column) == 0:
        return np.zeros((0, *shape), dtype=np.float16)
    expected = 2 * math.prod(shape)
    lengths = pc.binary_length(column).fill_null(-1).to_numpy(zero_copy_only=False)
    wrong = np.flatnonzero(lengths != expected)
    if len(wrong):
        got = "null" if lengths[wrong[0]] < 0 else f"{lengths[wrong[0]]:,} bytes"
        raise DataFormatError(path, f"row {wrong[0]}: a feature of {got} where the shape "
                                    f"{','.join(map(str, shape))} in float16 takes {expected:,} bytes; {PREPARE_AGAIN}",
                              field="roi_feature")
    features = _values_end_to_end(column, expected).view("<f2").reshape(len(column), *shape)
    broken = np.flatnonzero(~np.isfinite(features).reshape(len(features), -1).all(axis=1))
    if len(broken):  # prepare never writes one: a NaN would train on, or fail the validation's ROC
        raise DataFormatError(path, f"row {broken[0]}: a feature holding NaN or infinity; {PREPARE_AGAIN}",
                              field="roi_feature")
    return features


def _values_end_to_end(column: pa.ChunkedArray | pa.Array, width: int) -> np.ndarray:
    """The bytes of a binary column whose values are all ``width`` bytes long and none null, as
    one uint8 array read from the Arrow buffers (no Python object per row)."""
    chunks = column.chunks if isinstance(column, pa.ChunkedArray) else [column]
    parts = []
    for chunk in chunks:
        fixed = pc.cast(chunk, pa.binary(width))  # a fixed-size binary array keeps its values end to end
        start = fixed.offset * width
        parts.append(np.frombuffer(fixed.buffers()[1], np.uint8)[start:start + len(fixed) * width])
    return np.concatenate(parts)
