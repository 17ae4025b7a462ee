"""Write a dataset in the nuScenes v1.0 on-disk format, one record at a time.

Used by the synthetic dataset generator. Each table streams to ``<table>.json.partial`` as a
JSON list with one record per line, so memory stays flat whatever the dataset size;
:meth:`DatasetWriter.close` finishes the lists and renames them to ``<table>.json``. Output is
deterministic: the same records added in the same order give byte-identical files.
"""

from __future__ import annotations

import hashlib
import io
import json
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Mapping, Sequence

import numpy as np
from PIL import Image

from sianms_cli.errors import OutputExistsError
from sianms_cli.io import AtomicFile, make_folder, os_errors_as_output_errors, write_bytes
from sianms_cli.nuscenes.tables import (
    ATTRIBUTES,
    CATEGORIES,
    SCHEMAS,
    SENSORS,
    TABLE_NAMES,
    VISIBILITIES,
    check_value,
)

_MAP_RASTER_SIZE_PX = 8


def make_token(*parts: object) -> str:
    """A deterministic 32-hex-character token: md5 of the parts' ``str`` forms.

    The parts are encoded as a JSON list before hashing, so ``("a/b", "c")`` and ``("a", "b/c")``
    give different tokens; ``3`` and ``"3"`` give the same. At least one part is required.
    """
    if not parts:
        raise ValueError("make_token needs at least one part")
    text = json.dumps([str(part) for part in parts], ensure_ascii=False)
    return hashlib.md5(text.encode("utf-8")).hexdigest()


def category_token(name: str) -> str:
    """The token :meth:`DatasetWriter.add_static_tables` gives the category ``name``."""
    if name not in {c.name for c in CATEGORIES}:
        raise ValueError(f"unknown category {name!r}")
    return make_token("category", name)


def attribute_token(name: str) -> str:
    """The token :meth:`DatasetWriter.add_static_tables` gives the attribute ``name``."""
    if name not in {a.name for a in ATTRIBUTES}:
        raise ValueError(f"unknown attribute {name!r}")
    return make_token("attribute", name)


_JSON_SCALAR_TYPES = frozenset((str, int, float, bool))


def _plain(value: Any) -> Any:
    """``value`` with numpy arrays and scalars, and tuples, turned into JSON's Python types."""
    if type(value) in _JSON_SCALAR_TYPES:
        return value
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [v if type(v) in _JSON_SCALAR_TYPES else _plain(v) for v in value]
    return value


def checked_record(table: str, record: Mapping[str, Any]) -> dict[str, Any]:
    """``record`` as it will be written: fields in schema order, numpy values made plain.

    Raises ValueError naming the table, the record token and the field for an unknown table,
    a missing or unknown field, or a value of the wrong kind. References to other records are
    not resolved here; the loader checks them.
    """
    schema = SCHEMAS.get(table)
    if schema is None:
        raise ValueError(f"unknown table {table!r}; tables: {', '.join(TABLE_NAMES)}")
    token = record.get("token", "<no token>")
    for field in record:
        if field not in schema:
            raise ValueError(
                f"{table} record {token}: field {field!r}: not in the {table} schema "
                f"({', '.join(schema)})"
            )
    plain = {}
    for field, kind in schema.items():
        if field not in record:
            raise ValueError(f"{table} record {token}: field {field!r}: missing")
        value = _plain(record[field])
        problem = check_value(kind, value)
        if problem is not None:
            raise ValueError(f"{table} record {token}: field {field!r}: {problem}")
        plain[field] = value
    return plain


def _map_raster_png() -> bytes:
    buffer = io.BytesIO()
    blank = np.zeros((_MAP_RASTER_SIZE_PX, _MAP_RASTER_SIZE_PX), dtype=np.uint8)
    Image.fromarray(blank).save(buffer, format="PNG")
    return buffer.getvalue()


class DatasetWriter:
    """Streams the 13 tables of ``<dataroot>/<version>/``, plus map rasters and ``splits.json``.

    Records are written in the order they are added, each checked against the schema
    (:func:`checked_record`). Use as a context manager: a clean exit calls :meth:`close`; an
    exception calls :meth:`abort`, which deletes the partial files and leaves any previously
    finished tables untouched.

    Refuses (:class:`OutputExistsError`) a version folder that already holds finished tables
    unless ``overwrite`` is true; then the 13 tables are replaced at :meth:`close`. Map rasters
    and ``splits.json`` are replaced when written; nothing else in the folder is touched.
    """

    def __init__(self, dataroot: str | Path, version: str, *, overwrite: bool = False) -> None:
        self.dataroot = Path(dataroot)
        self.version = version
        self.table_root = self.dataroot / version
        finished = [name for name in TABLE_NAMES if self._final_path(name).exists()]
        if finished and not overwrite:
            raise OutputExistsError(
                f"{self.table_root}: already holds finished tables ({', '.join(finished)}); "
                "pass overwrite to replace them"
            )
        make_folder(self.table_root)
        self._files: dict[str, AtomicFile] = {}
        self._counts = dict.fromkeys(TABLE_NAMES, 0)
        self._closed = False

    def _final_path(self, table: str) -> Path:
        return self.table_root / f"{table}.json"

    def _file(self, table: str) -> IO[str]:
        if table not in self._files:
            self._files[table] = AtomicFile(self._final_path(table), text=True)
        return self._files[table].stream

    def add(self, table: str, record: Mapping[str, Any]) -> None:
        """Check ``record`` against the ``table`` schema and append it to the table's file.

        Raises ValueError naming the table, token and field when the record does not fit
        the schema (see :func:`checked_record`), and when the writer is already closed.
        """
        if self._closed:
            raise ValueError(f"{self.table_root}: writer is closed")
        line = json.dumps(checked_record(table, record), allow_nan=False)
        separator = "[\n" if self._counts[table] == 0 else ",\n"
        with os_errors_as_output_errors(self._final_path(table)):
            self._file(table).write(separator + line)
        self._counts[table] += 1

    def count(self, table: str) -> int:
        """How many records were added to ``table`` so far."""
        return self._counts[table]

    def add_static_tables(self) -> None:
        """Add the fixed vocabularies: 23 categories, 8 attributes, 4 visibilities, 12 sensors.

        Category and attribute tokens are :func:`category_token` / :func:`attribute_token` of
        the name; visibility and sensor tokens are those of :mod:`~sianms_cli.nuscenes.tables`.
        """
        for category in CATEGORIES:
            self.add("category", {
                "token": category_token(category.name),
                "name": category.name,
                "description": category.description,
            })
        for attribute in ATTRIBUTES:
            self.add("attribute", {
                "token": attribute_token(attribute.name),
                "name": attribute.name,
                "description": attribute.description,
            })
        for visibility in VISIBILITIES:
            self.add("visibility", visibility._asdict())
        for sensor in SENSORS:
            self.add("sensor", sensor._asdict())

    def add_map(
        self, token: str, log_tokens: Sequence[str], category: str = "semantic_prior"
    ) -> None:
        """Write ``maps/<token>.png`` (a small blank raster) and add its map record.

        nuscenes-devkit requires every log to be listed in some map record's ``log_tokens``
        and the raster file to exist; it decodes the raster only when a map mask is used.
        """
        filename = f"maps/{token}.png"
        record = {"category": category, "token": token, "filename": filename,
                  "log_tokens": list(log_tokens)}
        checked_record("map", record)
        write_bytes(self.dataroot / filename, _map_raster_png())
        self.add("map", record)

    def write_splits(self, splits: Mapping[str, Sequence[str]]) -> None:
        """Write ``<version>/splits.json``: split name -> scene names, read for custom splits.

        Raises ValueError unless every key is a string and every value a list of strings.
        """
        plain = {}
        for name, scenes in splits.items():
            scenes = _plain(scenes)
            if not isinstance(name, str) or not isinstance(scenes, list) or not all(
                isinstance(scene, str) for scene in scenes
            ):
                raise ValueError(f"splits: {name!r} must map a name to a list of scene names")
            plain[name] = scenes
        text = json.dumps(plain, indent=2) + "\n"
        write_bytes(self.table_root / "splits.json", text.encode("utf-8"))

    def close(self) -> None:
        """Finish every table (an empty one is written as ``[]``) and rename it into place.

        A failure here (disk full while flushing) aborts, so no partial table stays behind.
        """
        if self._closed:
            return
        try:
            for table in TABLE_NAMES:
                with os_errors_as_output_errors(self._final_path(table)):
                    self._file(table).write("[]\n" if self._counts[table] == 0 else "\n]\n")
            for table in TABLE_NAMES:
                self._files.pop(table).commit()
        except BaseException:
            self.abort()
            raise
        self._closed = True

    def abort(self) -> None:
        """Stop writing and delete the partial table files; finished files are left alone."""
        for file in self._files.values():
            file.discard()
        self._files.clear()
        self._closed = True

    def __enter__(self) -> DatasetWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
