"""Indexed, columnar loader for the tables of a nuScenes v1.0 dataroot.

Each table is held column by column in numpy arrays, never as one Python object per record,
so a v1.0-trainval-sized set (1.2 M annotations, 2.6 M sample_data) fits in a few GB:

- ``token`` and ``str`` fields: numpy string arrays (``str`` fields stored UTF-8 encoded);
- ``int`` fields: int64 (timestamps in microseconds stay exact); ``bool``: bool;
- ``vector`` fields: float64 of shape (N, k); ``camera_intrinsic``: float64 (N, 3, 3), NaN
  where the record holds ``[]``;
- token references: resolved once at load to int64 row indices into the referenced table,
  -1 for ``""``; a list of tokens becomes an (N, K) array padded with -1.

Tokens are looked up through :class:`~sianms_cli.nuscenes.token_index.TokenIndex`. Large table
files are decoded with orjson in runs of whole records (:func:`~sianms_cli.json_stream.
array_pieces`), so a trainval-sized load peaks at about twice what the loaded tables hold.

Loading validates everything the toolkit relies on and stops at the first problem with one
:class:`~sianms_cli.errors.DataFormatError` naming the file, the record token and the field,
including values no real record holds (:data:`_VALUE_RULES`). Fields outside the schema and
optional extra tables (lidarseg, panoptic, image annotations) are ignored.
"""

from __future__ import annotations

from functools import cached_property
from itertools import chain
from operator import itemgetter
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, NamedTuple

import numpy as np

from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.json_stream import array_pieces, collector_paused, types_within
from sianms_cli.nuscenes.sensors import read_image, read_pcd_bin, resolve_data_path
from sianms_cli.nuscenes.tables import NUL, SCHEMAS, TABLE_NAMES, Field, check_value, check_version_name
from sianms_cli.nuscenes.token_index import TokenIndex

_REF_KINDS = ("ref", "optional_ref", "ref_list")
_TEXT_ENCODING = "utf-8"
# Lone surrogates (legal in JSON escapes) survive the round trip through bytes.
_TEXT_ERRORS = "surrogatepass"
# A table file larger than this is decoded in pieces of about this much text.
_CHUNK_BYTES = 32 * 2**20


# --------------------------------------------------------------------------- decoding


def _record_error(
    path: Path, records: list, i: int, first: int, field: str, problem: str
) -> DataFormatError:
    """The error for record ``i`` of ``records``, the ``first``-th record of the file onwards."""
    token = records[i].get("token")
    if isinstance(token, str) and token:
        return DataFormatError(path, problem, token=token, field=field)
    return DataFormatError(path, f"record at position {first + i}: {problem}", field=field)


def _field_values(path: Path, records: list, first: int, field: str) -> list:
    try:
        return list(map(itemgetter(field), records))
    except KeyError:
        i = next(i for i, record in enumerate(records) if field not in record)
        raise _record_error(path, records, i, first, field, "missing") from None


def _diagnose(
    path: Path, records: list, first: int, values: list, field: str, kind: Field
) -> DataFormatError:
    """The error for the first value of ``field`` that breaks its kind."""
    for i, value in enumerate(values):
        problem = check_value(kind, value)
        if problem is not None:
            return _record_error(path, records, i, first, field, problem)
    raise AssertionError(f"{path}: {field}: fast check rejected values the exact check accepts")


def _is_text(values: list) -> bool:
    return types_within(values, (str,)) and NUL not in "".join(values)


def _strings(values: list, allow_empty: bool) -> np.ndarray | None:
    if not _is_text(values):
        return None
    # An explicit width saves numpy a second pass to discover it.
    array = np.array(values, dtype=f"<U{max(map(len, values), default=1) or 1}")
    if not allow_empty and (array == "").any():
        return None
    return array


def _vectors(values: list, length: int) -> np.ndarray | None:
    if not types_within(values, (list,)) or not set(map(len, values)) <= {length}:
        return None
    if not types_within(chain.from_iterable(values), (float, int)):
        return None
    try:
        array = np.fromiter(chain.from_iterable(values), dtype=np.float64,
                            count=len(values) * length).reshape(len(values), length)
    except OverflowError:
        return None
    return array if np.isfinite(array).all() else None


def _intrinsics(values: list) -> np.ndarray | None:
    kind = SCHEMAS["calibrated_sensor"]["camera_intrinsic"]
    if any(check_value(kind, value) is not None for value in values):
        return None
    array = np.full((len(values), 3, 3), np.nan)
    for i, value in enumerate(values):
        if value:
            array[i] = value
    return array


def _token_lists(values: list) -> tuple[np.ndarray, np.ndarray] | None:
    """(lengths (N,), all tokens flattened) of a list-of-tokens field."""
    if not types_within(values, (list,)):
        return None
    flat = _strings(list(chain.from_iterable(values)), allow_empty=False)
    if flat is None:
        return None
    return np.fromiter(map(len, values), dtype=np.int64, count=len(values)), flat


def _convert(values: list, kind: Field) -> Any:
    """The column for ``values`` of ``kind``, or None when some value breaks the kind."""
    if kind.kind in ("token", "ref"):
        return _strings(values, allow_empty=False)
    if kind.kind == "optional_ref":
        return _strings(values, allow_empty=True)
    if kind.kind == "str":
        if not _is_text(values):
            return None
        # Stored encoded: 1 byte per ASCII character instead of 4 (filenames of 2.6 M records).
        return np.array([value.encode(_TEXT_ENCODING, _TEXT_ERRORS) for value in values],
                        dtype=bytes)
    if kind.kind == "int":
        if not types_within(values, (int,)):
            return None
        try:
            return np.fromiter(values, dtype=np.int64, count=len(values))
        except OverflowError:
            return None
    if kind.kind == "bool":
        return np.array(values, dtype=bool) if types_within(values, (bool,)) else None
    if kind.kind == "vector":
        return _vectors(values, kind.length)
    if kind.kind == "intrinsic":
        return _intrinsics(values)
    assert kind.kind == "ref_list", kind
    return _token_lists(values)


# Squares of components within these bounds neither overflow nor underflow in float64, so the
# norm that every consumer divides by (sianms_cli.geometry.quaternion) is finite and non-zero.
_ROTATION_COMPONENT_RANGE = (1e-150, 1e150)


class _ValueRule(NamedTuple):
    """What a field's values must be beyond their kind: ``holds`` maps the field's column
    (N, ...) to (N,) bool, true where the value is acceptable."""

    holds: Callable[[np.ndarray], np.ndarray]
    expectation: str


MAX_BOX_SIZE = 1000.0
"""Metres: no annotated object is larger; a size past it is a unit or typing slip, and near
float64's range its corners would overflow."""


def _box_sizes(column: np.ndarray) -> np.ndarray:
    return np.all((column > 0) & (column <= MAX_BOX_SIZE), axis=1)


def _non_negative(column: np.ndarray) -> np.ndarray:
    return column >= 0


def _normalisable(column: np.ndarray) -> np.ndarray:
    # The largest component bounds the norm within a factor of 2 and is computed without
    # overflow, unlike the norm itself.
    largest = np.abs(column).max(axis=1)
    low, high = _ROTATION_COMPONENT_RANGE
    return (largest >= low) & (largest <= high)


MAX_COORDINATE = 1e8
"""Metres: no map coordinate is larger (the Earth's circumference is 4e7 m; UTM northings reach
1e7). A value near float64's limit overflows every projection's products."""
MAX_PIXELS = 1e6
"""Pixels: no focal length or principal point is larger (a 1600 px nuScenes camera has ~1,266)."""


def _coordinates(column: np.ndarray) -> np.ndarray:
    return (np.abs(column) <= MAX_COORDINATE).all(axis=1)


def _pixel_entries(column: np.ndarray) -> np.ndarray:  # NaN: a sensor without one ([])
    return (np.isnan(column) | (np.abs(column) <= MAX_PIXELS)).all(axis=(1, 2))


_TRANSLATION_RULE = _ValueRule(_coordinates, f"3 coordinates within ±{MAX_COORDINATE:g} m")
_ROTATION_RULE = _ValueRule(
    _normalisable,
    "a quaternion that can be normalised (largest |component| in "
    f"[{_ROTATION_COMPONENT_RANGE[0]:g}, {_ROTATION_COMPONENT_RANGE[1]:g}])",
)
_COUNT_RULE = _ValueRule(_non_negative, "a count of 0 or more")

_VALUE_RULES: dict[tuple[str, str], _ValueRule] = {
    ("calibrated_sensor", "rotation"): _ROTATION_RULE,
    ("calibrated_sensor", "translation"): _TRANSLATION_RULE,
    ("calibrated_sensor", "camera_intrinsic"): _ValueRule(_pixel_entries, f"entries within ±{MAX_PIXELS:g} px"),
    ("ego_pose", "rotation"): _ROTATION_RULE,
    ("ego_pose", "translation"): _TRANSLATION_RULE,
    ("sample_annotation", "translation"): _TRANSLATION_RULE,
    ("sample_annotation", "size"): _ValueRule(_box_sizes, f"3 sizes greater than 0 and at most {MAX_BOX_SIZE:,.0f} m"),
    ("sample_annotation", "rotation"): _ROTATION_RULE,
    ("sample_annotation", "num_lidar_pts"): _COUNT_RULE,
    ("sample_annotation", "num_radar_pts"): _COUNT_RULE,
    ("instance", "nbr_annotations"): _COUNT_RULE,
    ("sample_data", "width"): _ValueRule(_non_negative, "a width of 0 or more pixels (0: not an image)"),
    ("sample_data", "height"): _ValueRule(_non_negative, "a height of 0 or more pixels (0: not an image)"),
}
"""(table, field) -> the rule its values follow beyond their kind."""


def _check_rule(path: Path, records: list, first: int, values: list, field: str,
                column: np.ndarray, rule: _ValueRule) -> None:
    """Raise the error for the first value of ``column`` that breaks ``rule``, quoting it as
    the file holds it (``values``)."""
    broken = ~rule.holds(column)
    if broken.any():
        i = _first_row(broken)
        raise _record_error(path, records, i, first, field,
                            f"expected {rule.expectation}, got {values[i]!r}")


def _concatenate(pieces: list) -> Any:
    if isinstance(pieces[0], tuple):
        return tuple(np.concatenate(parts) for parts in zip(*pieces))
    return np.concatenate(pieces)


class _ParsedTable:
    """One table file decoded into columns and indexed by token.

    A token reference becomes rows (in ``rows``) while the file is decoded when its table is
    already parsed, right after when it is this table; otherwise it stays strings (in
    ``columns``) until :meth:`resolve_references` is given its table. Turning references to
    rows piece by piece keeps few token strings alive at once (GBs on v1.0-trainval).
    """

    def __init__(self, name: str, path: Path, parsed: Mapping[str, _ParsedTable]) -> None:
        self.name = name
        self.path = path
        self.schema = SCHEMAS[name]
        self.columns: dict[str, Any] = {}
        self.rows: dict[str, np.ndarray] = {}
        self._unresolved: dict[str, Field] = {}
        with collector_paused():
            pieces = self._decode(parsed)
        self.tokens: np.ndarray = _concatenate(pieces.pop("token"))
        self.index = TokenIndex(self.tokens)
        self._check_unique()
        for field, kind in self.schema.items():
            if field == "token":
                continue
            column = _concatenate(pieces.pop(field))
            if kind.kind not in _REF_KINDS:
                self.columns[field] = column
            elif kind.table in parsed:
                self._store_rows(field, column)
            elif kind.table == name:
                self._store_rows(field, self._resolve(field, kind, column, self.index,
                                                      self.tokens))
            else:
                self.columns[field] = column
                self._unresolved[field] = kind

    def _decode(self, parsed: Mapping[str, _ParsedTable]) -> dict[str, list]:
        """Per field, the column of each piece of the file; references to tables in
        ``parsed`` already as rows."""
        fields = ["token", *(field for field in self.schema if field != "token")]
        pieces: dict[str, list] = {field: [] for field in fields}
        first = 0
        for records in array_pieces(self.path, _CHUNK_BYTES):
            self._check_records(records, first)
            for field in fields:
                kind = self.schema[field]
                values = _field_values(self.path, records, first, field)
                column = _convert(values, kind)
                if column is None:
                    raise _diagnose(self.path, records, first, values, field, kind)
                rule = _VALUE_RULES.get((self.name, field))
                if rule is not None:
                    _check_rule(self.path, records, first, values, field, column, rule)
                del values
                if kind.kind in _REF_KINDS and kind.referenced_table in parsed:
                    column = self._resolve(field, kind, column, parsed[kind.referenced_table].index,
                                           pieces["token"][-1])
                pieces[field].append(column)
            first += len(records)
        return pieces

    def _check_records(self, records: Any, first: int) -> None:
        if not isinstance(records, list):
            raise DataFormatError(
                self.path, f"top level must be a list of records, got {type(records).__name__}"
            )
        if not types_within(records, (dict,)):
            i = next(i for i, record in enumerate(records) if not isinstance(record, dict))
            raise DataFormatError(
                self.path,
                f"record at position {first + i} is a {type(records[i]).__name__}, not an object",
            )

    def _check_unique(self) -> None:
        duplicate = self.index.first_duplicate()
        if duplicate is not None:
            earlier, later = duplicate
            raise DataFormatError(
                self.path,
                f"duplicate token (records at positions {earlier} and {later})",
                token=str(self.tokens[later]),
                field="token",
            )

    def check_filenames(self, dataroot: Path) -> None:
        """Raise DataFormatError for the first ``filename`` that leaves the dataroot."""
        names = self.columns["filename"]
        # Only a name that is absolute or holds ".." can leave the dataroot lexically; the
        # exact check runs on those few.
        suspects = np.char.startswith(names, b"/") | (np.char.find(names, b"..") >= 0)
        for i in np.flatnonzero(suspects):
            resolve_data_path(dataroot, names[i].decode(_TEXT_ENCODING, _TEXT_ERRORS),
                              table_path=self.path, token=str(self.tokens[i]))

    @property
    def resolved(self) -> bool:
        return not self._unresolved

    def resolve_references(self, parsed: Mapping[str, _ParsedTable]) -> None:
        """Turn the references to every table in ``parsed`` into rows; DataFormatError for
        the first token that is not in its table."""
        for field, kind in list(self._unresolved.items()):
            target = parsed.get(kind.referenced_table)
            if target is not None:
                column = self.columns.pop(field)
                self._store_rows(field, self._resolve(field, kind, column, target.index,
                                                      self.tokens))
                del self._unresolved[field]

    def _store_rows(self, field: str, rows: Any) -> None:
        if self.schema[field].kind == "ref_list":
            rows = _padded(*rows)
        self.rows[field] = rows

    def _resolve(self, field: str, kind: Field, column: Any, index: TokenIndex,
                 record_tokens: np.ndarray) -> Any:
        """Rows of a reference column: (N,) for one token per record, -1 for ""; for a list of
        tokens per record (lengths (N,), rows of all the tokens). ``record_tokens`` (N,) name
        the records in the error for a token missing from ``index``."""
        if kind.kind == "ref_list":
            lengths, tokens = column
            too_long = lengths > len(index)  # the lists are padded to the longest: one long list would take it all
            if too_long.any():
                i = _first_row(too_long)
                raise DataFormatError(self.path, f"lists {lengths[i]:,} tokens, more than {kind.table}.json's "
                                                 f"{len(index):,}: one repeats", token=str(record_tokens[i]),
                                      field=field)
            owners = np.repeat(np.arange(len(lengths)), lengths)
        else:
            tokens = column
            owners = np.arange(len(tokens))
        rows = index.lookup(tokens)
        dangling = (rows < 0) & (tokens != "")
        if dangling.any():
            i = _first_row(dangling)
            raise DataFormatError(
                self.path,
                f"refers to {kind.table} token '{tokens[i]}', which is not in {kind.table}.json",
                token=str(record_tokens[owners[i]]),
                field=field,
            )
        return (lengths, rows) if kind.kind == "ref_list" else rows


def _padded(lengths: np.ndarray, flat_rows: np.ndarray) -> np.ndarray:
    """(N, K) rows, K the longest list, padded with -1, from the lists' lengths (N,) and all
    their rows one after the other."""
    width = int(lengths.max()) if len(lengths) else 0
    padded = np.full((len(lengths), width), -1, dtype=np.int64)
    owners = np.repeat(np.arange(len(lengths)), lengths)
    starts = np.cumsum(lengths) - lengths
    padded[owners, np.arange(len(flat_rows)) - starts[owners]] = flat_rows
    return padded


def _first_row(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask)[0])


def _freeze(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


# --------------------------------------------------------------------------- tables


class Table:
    """One nuScenes table, held column by column; row ``i`` is the i-th record of the file.

    Read-only: the arrays returned share memory with the table and cannot be written to.
    """

    def __init__(
        self,
        name: str,
        path: Path,
        tokens: np.ndarray,
        index: TokenIndex,
        columns: dict[str, np.ndarray],
        rows: dict[str, np.ndarray],
        tables: Mapping[str, Table],
    ) -> None:
        self.name = name
        self.path = path
        self.schema = SCHEMAS[name]
        self._tokens = _freeze(tokens)
        self._index = index
        self._columns = {field: _freeze(column) for field, column in columns.items()}
        self._rows = {field: _freeze(column) for field, column in rows.items()}
        self._tables = tables

    def __len__(self) -> int:
        return len(self._tokens)

    def __repr__(self) -> str:
        return f"Table({self.name!r}, {len(self)} records)"

    @property
    def tokens(self) -> np.ndarray:
        """(N,) str: the token of every record, in file order."""
        return self._tokens

    @property
    def fields(self) -> tuple[str, ...]:
        """The schema's fields, ``token`` included, in file order."""
        return tuple(self.schema)

    def _kind(self, field: str) -> Field:
        kind = self.schema.get(field)
        if kind is None:
            raise KeyError(
                f"table {self.name} has no field {field!r}; fields: {', '.join(self.schema)}"
            )
        return kind

    def column(self, field: str) -> np.ndarray:
        """All values of ``field``, one per row.

        Shapes and dtypes: ``token``/``str``/``ref``/``optional_ref`` (N,) str, ``""`` where an
        optional reference is empty; ``ref_list`` (N, K) str padded with ``""``; ``int`` (N,)
        int64; ``bool`` (N,) bool; ``vector`` (N, k) float64; ``camera_intrinsic`` (N, 3, 3)
        float64, NaN where the record holds ``[]``. Unknown field: KeyError.
        """
        kind = self._kind(field)
        if kind.kind == "token":
            return self._tokens
        if kind.kind in _REF_KINDS:
            return self._referenced_tokens(kind.referenced_table, self._rows[field])
        if kind.kind == "str":
            return np.char.decode(self._columns[field], _TEXT_ENCODING, _TEXT_ERRORS)
        return self._columns[field]

    def _referenced_tokens(self, table: str, rows: np.ndarray) -> np.ndarray:
        tokens = self._tables[table].tokens
        if len(tokens) == 0:
            return np.full(rows.shape, "", dtype=str)
        return np.where(rows >= 0, tokens[np.maximum(rows, 0)], "")

    def rows(self, field: str) -> np.ndarray:
        """int64 rows into the referenced table for a token-reference field; -1 for ``""``.

        Shape (N,) for ``ref``/``optional_ref``, (N, K) padded with -1 for ``ref_list``.
        Raises KeyError for an unknown field or one that is not a token reference.
        """
        kind = self._kind(field)
        if kind.kind not in _REF_KINDS:
            raise KeyError(f"{self.name}.{field} is not a token reference")
        return self._rows[field]

    def record(self, i: int) -> dict[str, Any]:
        """Row ``i`` rebuilt as the JSON record (schema fields only, in file order)."""
        i = range(len(self))[i]
        record: dict[str, Any] = {}
        for field, kind in self.schema.items():
            if kind.kind == "token":
                value: Any = str(self._tokens[i])
            elif kind.kind in ("ref", "optional_ref"):
                row = int(self._rows[field][i])
                value = str(self._tables[kind.referenced_table].tokens[row]) if row >= 0 else ""
            elif kind.kind == "ref_list":
                referenced = self._tables[kind.referenced_table].tokens
                value = [str(referenced[row]) for row in self._rows[field][i] if row >= 0]
            elif kind.kind == "str":
                value = self._columns[field][i].decode(_TEXT_ENCODING, _TEXT_ERRORS)
            elif kind.kind == "intrinsic":
                matrix = self._columns[field][i]
                value = [] if np.isnan(matrix).all() else matrix.tolist()
            else:
                value = self._columns[field][i].tolist()
            record[field] = value
        return record

    def index(self, token: str) -> int:
        """The row of ``token``; DataFormatError naming this table's file if it is absent."""
        return int(self.indices([token])[0])

    def indices(self, tokens: Iterable[str], *, allow_missing: bool = False) -> np.ndarray:
        """int64 rows of ``tokens`` (any iterable or array of str), in the given order.

        An absent token raises DataFormatError naming this table's file and the token, or
        gives -1 when ``allow_missing`` is true.
        """
        if isinstance(tokens, str):
            raise TypeError("indices() takes a sequence of tokens; use index() for one token")
        queries = np.asarray(tokens if isinstance(tokens, np.ndarray) else list(tokens), dtype=str)
        rows = self._index.lookup(queries.reshape(-1))
        if not allow_missing and (rows < 0).any():
            missing = queries.reshape(-1)[_first_row(rows < 0)]
            raise DataFormatError(self.path, f"no {self.name} record has token '{missing}'")
        return rows.reshape(queries.shape)


# --------------------------------------------------------------------------- database


def version_folder(dataroot: str | Path, version: str) -> Path:
    """``<dataroot>/<version>/``, the folder of the 13 tables; DataFormatError where it is not one."""
    folder = Path(dataroot) / check_version_name(version)
    if not folder.is_dir():
        raise DataFormatError(folder, "version folder not found (expected <dataroot>/<version>/)")
    return folder


class NuScenesDB:
    """The 13 tables of ``<dataroot>/<version>/``, indexed, with the devkit's reverse links.

    Loading validates every table (see the module docstring) and raises one
    :class:`DataFormatError` at the first problem. Sensor files are not opened at load.
    """

    def __init__(self, dataroot: str | Path, version: str) -> None:
        self.dataroot = Path(dataroot)
        self.table_root = version_folder(dataroot, version)
        self.version = version
        paths = {name: self.table_root / f"{name}.json" for name in TABLE_NAMES}
        missing = [name for name in TABLE_NAMES if not paths[name].is_file()]
        if missing:
            others = f" (also missing: {', '.join(missing[1:])})" if missing[1:] else ""
            what = "is a folder, not a table file" if paths[missing[0]].is_dir() else "table file not found"
            raise DataFormatError(paths[missing[0]], f"{what}{others}")
        parsed: dict[str, _ParsedTable] = {}
        for name in TABLE_NAMES:
            table = _ParsedTable(name, paths[name], parsed)
            if "filename" in table.columns:
                table.check_filenames(self.dataroot)
            parsed[name] = table
            for earlier in parsed.values():
                earlier.resolve_references(parsed)
        assert all(table.resolved for table in parsed.values())
        self._tables: dict[str, Table] = {}
        for name, table in parsed.items():
            self._tables[name] = Table(name, table.path, table.tokens, table.index,
                                       table.columns, table.rows, self._tables)

    # ----------------------------------------------------------------------- access

    def table(self, name: str) -> Table:
        """The table ``name`` (one of TABLE_NAMES); KeyError for any other name."""
        table = self._tables.get(name)
        if table is None:
            raise KeyError(f"no table {name!r}; tables: {', '.join(TABLE_NAMES)}")
        return table

    def get(self, table: str, token: str) -> dict[str, Any]:
        """The record ``token`` of ``table`` as the devkit's ``NuScenes.get`` returns it.

        Adds the devkit's reverse fields: ``category_name`` on sample_annotation; ``channel``
        and ``sensor_modality`` on sample_data; on sample, ``data`` {channel: key-frame
        sample_data token} and ``anns`` [annotation tokens in file order].
        """
        records = self.table(table)
        row = records.index(token)
        record = records.record(row)
        if table == "sample_annotation":
            instance = records.rows("instance_token")[row]
            category = self.table("instance").rows("category_token")[instance]
            record["category_name"] = self.table("category").record(category)["name"]
        elif table == "sample_data":
            sensor = self.table("sensor").record(self._sample_data_sensor_rows[row])
            record["channel"] = sensor["channel"]
            record["sensor_modality"] = sensor["modality"]
        elif table == "sample":
            record["data"] = self._keyframe_data_of_row(row)
            annotations = self.table("sample_annotation").tokens
            record["anns"] = annotations[self._annotation_rows_of_row(row)].tolist()
        return record

    @cached_property
    def _sample_data_sensor_rows(self) -> np.ndarray:
        calibrated = self.table("calibrated_sensor").rows("sensor_token")
        return calibrated[self.table("sample_data").rows("calibrated_sensor_token")]

    def sample_data_channels(self) -> np.ndarray:
        """(N,) str: the sensor channel of every sample_data row (e.g. ``CAM_FRONT``)."""
        return self.table("sensor").column("channel")[self._sample_data_sensor_rows]

    def sample_data_modalities(self) -> np.ndarray:
        """(N,) str: ``camera``, ``lidar`` or ``radar`` for every sample_data row."""
        return self.table("sensor").column("modality")[self._sample_data_sensor_rows]

    def annotation_category_names(self) -> np.ndarray:
        """(N,) str: the category name of every sample_annotation row."""
        categories = self.table("instance").rows("category_token")
        instances = self.table("sample_annotation").rows("instance_token")
        return self.table("category").column("name")[categories[instances]]

    @staticmethod
    def _group(owners: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
        """(order, offsets): the items of owner r are order[offsets[r]:offsets[r + 1]]."""
        order = np.argsort(owners, kind="stable")
        offsets = np.zeros(count + 1, dtype=np.int64)
        np.cumsum(np.bincount(owners, minlength=count), out=offsets[1:])
        return order, offsets

    @cached_property
    def _annotations_by_sample(self) -> tuple[np.ndarray, np.ndarray]:
        owners = self.table("sample_annotation").rows("sample_token")
        return self._group(owners, len(self.table("sample")))

    @cached_property
    def _keyframes_by_sample(self) -> tuple[np.ndarray, np.ndarray]:
        sample_data = self.table("sample_data")
        keyframes = np.flatnonzero(sample_data.column("is_key_frame"))
        order, offsets = self._group(sample_data.rows("sample_token")[keyframes],
                                     len(self.table("sample")))
        return keyframes[order], offsets

    def _annotation_rows_of_row(self, sample_row: int) -> np.ndarray:
        order, offsets = self._annotations_by_sample
        return order[offsets[sample_row]:offsets[sample_row + 1]].copy()

    def _keyframe_data_of_row(self, sample_row: int) -> dict[str, str]:
        rows, offsets = self._keyframes_by_sample
        mine = rows[offsets[sample_row]:offsets[sample_row + 1]]
        channels = self.table("sensor").column("channel")[self._sample_data_sensor_rows[mine]]
        tokens = self.table("sample_data").tokens[mine]
        # Rows are in file order, so a later key frame of the same channel wins, as in the devkit.
        return {str(channel): str(token) for channel, token in zip(channels, tokens)}

    def sample_annotation_rows(self, sample_token: str) -> np.ndarray:
        """int64 rows of the sample's annotations in the sample_annotation table, file order."""
        return self._annotation_rows_of_row(self.table("sample").index(sample_token))

    def keyframe_data(self, sample_token: str) -> dict[str, str]:
        """{channel: key-frame sample_data token} of a sample (the devkit's ``sample['data']``)."""
        return self._keyframe_data_of_row(self.table("sample").index(sample_token))

    def sample_tokens_of_scene(self, scene_token: str) -> list[str]:
        """The scene's sample tokens in time order, walking first_sample_token and next.

        A chain that leaves the scene, loops, stops before ``last_sample_token`` or goes on after
        it, or whose length differs from ``nbr_samples`` raises DataFormatError naming the record
        and field.
        """
        scenes = self.table("scene")
        samples = self.table("sample")
        scene_row = scenes.index(scene_token)
        sample_scene_rows = samples.rows("scene_token")
        next_rows = samples.rows("next")
        row = int(scenes.rows("first_sample_token")[scene_row])
        last = int(scenes.rows("last_sample_token")[scene_row])
        if sample_scene_rows[row] != scene_row:
            raise DataFormatError(
                scenes.path,
                f"first sample {samples.tokens[row]} belongs to scene "
                f"{scenes.tokens[sample_scene_rows[row]]}",
                token=scene_token, field="first_sample_token",
            )
        chain_rows = [row]
        seen = {row}
        while row != last:
            following = int(next_rows[row])
            if following < 0:
                problem = (f"chain of scene {scene_token} ends before its last sample "
                           f"{samples.tokens[last]}")
            elif sample_scene_rows[following] != scene_row:
                problem = (f"next sample {samples.tokens[following]} belongs to scene "
                           f"{scenes.tokens[sample_scene_rows[following]]}, not {scene_token}")
            elif following in seen:
                problem = f"next sample {samples.tokens[following]} was already visited (a loop)"
            else:
                problem = None
            if problem is not None:
                raise DataFormatError(samples.path, problem, token=str(samples.tokens[row]),
                                      field="next")
            row = following
            chain_rows.append(row)
            seen.add(row)
        if next_rows[last] >= 0:
            raise DataFormatError(samples.path, f"the last sample of scene {scene_token} has a next sample, "
                                  f"{samples.tokens[next_rows[last]]}", token=str(samples.tokens[last]), field="next")
        expected = int(scenes.column("nbr_samples")[scene_row])
        if len(chain_rows) != expected:
            raise DataFormatError(
                scenes.path,
                f"{expected} samples declared, {len(chain_rows)} along the first/next chain",
                token=scene_token, field="nbr_samples",
            )
        return samples.tokens[chain_rows].tolist()

    def ego_pose_of(self, sd_token: str) -> tuple[np.ndarray, np.ndarray]:
        """(rotation (4,) w,x,y,z ego->global, translation (3,) m global) of a sample_data."""
        sample_data = self.table("sample_data")
        row = sample_data.rows("ego_pose_token")[sample_data.index(sd_token)]
        poses = self.table("ego_pose")
        return poses.column("rotation")[row].copy(), poses.column("translation")[row].copy()

    def calibration_of(self, sd_token: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(rotation (4,) w,x,y,z sensor->ego, translation (3,) m in the ego frame, intrinsic)
        of a sample_data's sensor; the intrinsic is (3, 3) for cameras, None for lidar/radar."""
        sample_data = self.table("sample_data")
        row = sample_data.rows("calibrated_sensor_token")[sample_data.index(sd_token)]
        calibrated = self.table("calibrated_sensor")
        intrinsic = calibrated.column("camera_intrinsic")[row]
        return (
            calibrated.column("rotation")[row].copy(),
            calibrated.column("translation")[row].copy(),
            None if np.isnan(intrinsic).all() else intrinsic.copy(),
        )

    def data_path(self, sd_token: str) -> Path:
        """The sensor file of a sample_data, inside the dataroot (it need not exist)."""
        sample_data = self.table("sample_data")
        filename = sample_data.record(sample_data.index(sd_token))["filename"]
        return resolve_data_path(self.dataroot, filename, table_path=sample_data.path,
                                 token=sd_token)

    def _require_modality(self, sd_token: str, modality: str) -> None:
        row = self.table("sample_data").index(sd_token)
        sensor = self.table("sensor").record(self._sample_data_sensor_rows[row])
        if sensor["modality"] != modality:
            raise SianmsError(
                f"sample_data {sd_token} is from {sensor['channel']} ({sensor['modality']}), "
                f"not a {modality}"
            )

    def read_lidar(self, sd_token: str) -> np.ndarray:
        """(N, 5) float32 points of a lidar sample_data, sensor frame: x, y, z, intensity, ring.

        SianmsError if the record is not from a lidar; DataFormatError for a missing or
        truncated file."""
        self._require_modality(sd_token, "lidar")
        return read_pcd_bin(self.data_path(sd_token), sd_token)

    def read_image(self, sd_token: str) -> np.ndarray:
        """(H, W, 3) uint8 RGB image of a camera sample_data.

        SianmsError if the record is not from a camera; DataFormatError for a missing or
        undecodable file, or one whose size is not the record's ``width`` and ``height`` (boxes
        are projected and clipped to the record's size, ROI features pooled from the file)."""
        self._require_modality(sd_token, "camera")
        path = self.data_path(sd_token)
        image = read_image(path, sd_token)
        sample_data = self.table("sample_data")
        record = sample_data.record(sample_data.index(sd_token))
        if (image.shape[1], image.shape[0]) != (record["width"], record["height"]):
            raise DataFormatError(path, f"is {image.shape[1]}x{image.shape[0]} pixels, but its sample_data record "
                                  f"{sd_token} says width {record['width']}, height {record['height']}")
        return image
