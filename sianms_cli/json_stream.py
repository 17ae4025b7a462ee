"""Decoding big JSON documents a part at a time, and describing decoded values.

Two shapes of large document reach sianms, and each gets a reader that never holds the whole
document as Python objects:

- a top-level array of records (a nuScenes table; sample_data.json of v1.0-trainval is 1.3 GB):
  :func:`array_pieces` decodes it in runs of whole elements, cut where one object ends and the
  next begins;
- an object whose values are objects of lists (a results file; 1.2 M boxes are 0.5 GB):
  :class:`JsonStream` walks its top two levels incrementally and decodes each value whole.

Both decode with orjson wherever it can, and name the file, the line and the column of a syntax
error, as :func:`sianms_cli.io.decode_json` does for a whole document.

:func:`json_kind`, :func:`is_number` and :func:`types_within` describe and check decoded values,
for error messages and for the fast type checks that run before converting values to arrays.
"""

from __future__ import annotations

import gc
import json
import math
import mmap
import re
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Sequence, TypeGuard

import orjson

from sianms_cli.errors import DataFormatError
from sianms_cli.io import JSON_MAX_DEPTH, decode_json, nested_too_deep, read_json

_JSON_KINDS = {dict: "an object", list: "a list", str: "a string", bool: "a boolean",
               int: "a number", float: "a number", type(None): "null"}


def json_kind(value: Any) -> str:
    """What a decoded JSON value is, for messages: ``"an object"``, ``"a list"``, ``"a string"``,
    ``"a boolean"``, ``"a number"`` or ``"null"``; the type's name for anything else."""
    return _JSON_KINDS.get(type(value), type(value).__name__)


def is_number(value: Any) -> TypeGuard[int | float]:
    """Whether ``value`` is an int or a float, and not a bool (JSON ``true`` is no number)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def fits_float(values: Sequence[Any]) -> bool:
    """Whether every number of ``values`` converts to a float: an integer past float's range
    (JSON allows any length of digits) raises OverflowError in numpy and in ``float``."""
    try:
        [float(value) for value in values]
    except OverflowError:
        return False
    return True


def is_finite_number(value: Any) -> TypeGuard[int | float]:
    """Whether ``value`` is a number (:func:`is_number`) that is finite as a float: not NaN,
    not infinite (Python's json reads both) and not an integer past float's range."""
    if not is_number(value):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def types_within(values: Iterable, allowed: tuple[type, ...]) -> bool:
    """Whether the exact type of every value is one of ``allowed`` (bool is not int here)."""
    return set(map(type, values)) <= set(allowed)


@contextmanager
def collector_paused() -> Iterator[None]:
    """Pause the cyclic garbage collector.

    Decoding a table allocates millions of containers; the collector would rescan them over
    and over (several times slower on a trainval-sized table), and none of them forms a cycle.
    """
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


# --------------------------------------------------------------------------- arrays in runs

_LIST_START = re.compile(rb"[ \t\n\r]*\[")
_BETWEEN_OBJECTS = re.compile(rb"\}[ \t\n\r]*,[ \t\n\r]*(?=\{)")
_SPACE_TO_END = re.compile(rb"[ \t\n\r]*\Z")


def record_runs(data: Any, chunk_bytes: int) -> list[tuple[int, int]] | None:
    """Byte ranges [a, b) that split the top-level JSON array in ``data`` (bytes-like) into
    runs of about ``chunk_bytes``, cut where one object ends and the next begins (``}``,
    comma, ``{``); ``b"[" + data[a:b] + b"]"`` then holds the run's elements. None when
    ``data`` does not look like one array.

    The cuts are guesses (the pattern may sit inside a string or a nested object), verified
    by decoding: a run decodes only if it starts and ends on element boundaries of the
    document, because a JSON parser reads the run exactly as it reads the document from the
    run's start. So if every run decodes, together they decode the whole document.
    """
    opening = _LIST_START.match(data)
    close = data.rfind(b"]")
    if opening is None or close < opening.end() or not _SPACE_TO_END.match(data, close + 1):
        return None
    runs, begin = [], opening.end()
    while begin + chunk_bytes < close:
        between = _BETWEEN_OBJECTS.search(data, begin + chunk_bytes, close)
        if between is None:
            break
        runs.append((begin, between.start() + 1))
        begin = between.end()
    runs.append((begin, close))
    return runs


def array_pieces(path: Path, chunk_bytes: int) -> Iterator[Any]:
    """The decoded JSON file at ``path``, in pieces.

    A file larger than ``chunk_bytes`` holding a JSON array comes as consecutive lists of its
    elements, about ``chunk_bytes`` of text each: decoding a 1.3 GB sample_data.json whole
    peaks at about 5x its size (the parser's own document plus the Python objects), in
    pieces at one piece plus the file, memory-mapped (evictable). Any other file comes
    whole, once, whatever its type. Errors are those of :func:`sianms_cli.io.read_json`,
    and the same whether the file is decoded whole or in pieces.
    """
    if path.stat().st_size <= chunk_bytes:
        yield read_json(path)
        return
    with open(path, "rb") as handle, mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ) as data:
        runs = record_runs(data, chunk_bytes)
        if runs is None:
            yield decode_json(path, data[:])
            return
        consumed = 0
        for begin, end in runs:
            try:
                piece = orjson.loads(b"[" + data[begin:end] + b"]")
            except orjson.JSONDecodeError:
                # A malformed file, a cut guessed inside a string or a nested object, or a value
                # only the json module reads (NaN): decoding the whole file names the error
                # (with its line), or else recovers the remaining elements.
                whole = decode_json(path, data[:])
                assert isinstance(whole, list), type(whole)
                yield whole[consumed:]
                return
            consumed += len(piece)
            yield piece


# --------------------------------------------------------------------------- objects, streamed

_WHITESPACE = re.compile(r"[ \t\n\r]*")
_SIMPLE_STRING = re.compile(r'"([^"\\\x00-\x1f]*)"')
_EMPTY_LIST = re.compile(r"\[[ \t\n\r]*\]")
_LIST_END = re.compile(r"\}[ \t\n\r]*\]")


class JsonStream:
    """Incremental reader of the top two levels of a JSON object, decoding each value whole.

    The file is read ``chunk_chars`` characters at a time; a value cut by the end of the
    buffer is decoded again once more text is in. Consumed text is dropped, so memory holds
    about one chunk (or the largest value). ``progress``, when given, is called with the
    number of characters of each chunk read. Use as a context manager (it opens the file)::

        with JsonStream(path, chunk_chars=1 << 23) as stream:
            for key in stream.object_keys():
                value = stream.value()
    """

    def __init__(self, path: Path, *, chunk_chars: int,
                 progress: Callable[[int], None] | None = None) -> None:
        self.path = path
        self.chunk_chars = chunk_chars
        self.progress = progress
        self.decoder = json.JSONDecoder()
        self.buffer = ""
        self.pos = 0
        self.offset = 0  # characters of the file before the buffer
        self.eof = False

    def __enter__(self) -> JsonStream:
        try:
            self.file = open(self.path, encoding="utf-8-sig")
        except OSError as exc:
            raise DataFormatError(self.path, f"cannot open: {exc.strerror}") from None
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.file.close()

    def _fill(self, grow: bool = False) -> None:
        """Drop the consumed text and read a chunk; ``grow``: at least double the pending text
        (a value longer than a chunk is then re-decoded O(log n) times, not O(n / chunk))."""
        self.offset += self.pos
        size = max(self.chunk_chars, len(self.buffer) - self.pos) if grow else self.chunk_chars
        try:
            chunk = self.file.read(size)
        except UnicodeDecodeError as exc:
            raise DataFormatError(self.path, f"not valid UTF-8 ({exc.reason})") from None
        self.buffer = self.buffer[self.pos:] + chunk
        self.pos = 0
        self.eof = not chunk
        if self.progress is not None and chunk:
            self.progress(len(chunk))

    def _error(self, message: str, position: int | None = None) -> DataFormatError:
        """A DataFormatError at a buffer position, with the line and column in the file
        (counted by reading the file again: errors are rare, reads are hot)."""
        target = self.offset + (self.pos if position is None else position)
        line, column, seen = 1, 1, 0
        with open(self.path, encoding="utf-8-sig", errors="replace") as again:
            while seen < target:
                text = again.read(min(self.chunk_chars, target - seen))
                if not text:
                    break
                newlines = text.count("\n")
                line += newlines
                column = len(text) - text.rfind("\n") if newlines else column + len(text)
                seen += len(text)
        return DataFormatError(self.path, f"invalid JSON at line {line}, column {column}: {message}")

    def _skip_whitespace(self) -> str:
        """The next non-blank character ('' at the end of the file)."""
        while True:
            blank = _WHITESPACE.match(self.buffer, self.pos)
            assert blank is not None  # a starred pattern matches, if only the empty string
            self.pos = blank.end()
            if self.pos < len(self.buffer):
                return self.buffer[self.pos]
            if self.eof:
                return ""
            self._fill()

    def _expect(self, characters: str, what: str) -> str:
        found = self._skip_whitespace()
        if not found or found not in characters:
            raise self._error(f"expected {what}, found {found[:1] or 'the end of the file'!r}")
        self.pos += 1
        return found

    def value(self) -> Any:
        """Decode the next JSON value."""
        if self._skip_whitespace() == "[":
            fast = self._list_by_orjson()
            if fast is not None:
                return fast
        while True:
            try:
                value, end = self.decoder.raw_decode(self.buffer, self.pos)
            except json.JSONDecodeError as exc:
                if self.eof:
                    raise self._error(exc.msg, exc.pos) from None
                self._fill(grow=True)
                continue
            except RecursionError:
                raise self._error(f"nested deeper than {JSON_MAX_DEPTH} levels") from None
            if end == len(self.buffer) and not self.eof:
                self._fill(grow=True)  # a number or literal may go on in the next chunk
                continue
            if nested_too_deep(self.buffer[self.pos:end]):
                raise self._error(f"nested deeper than {JSON_MAX_DEPTH} levels")
            self.pos = end
            return value

    def _list_by_orjson(self) -> list | None:
        """The list starting here, decoded by orjson (several times faster), or None.

        The candidate end is the first ``}]`` (or ``[]`` right here): a slice that orjson
        decodes as a whole is exactly the list that starts here, since a JSON array ends at
        its matching bracket. Anything else (a ``}]`` inside a string, NaN, which orjson
        rejects, a list cut by the end of the buffer) returns None for the json module.
        """
        match = _EMPTY_LIST.match(self.buffer, self.pos) or _LIST_END.search(self.buffer, self.pos)
        if match is None:
            return None
        try:
            value = orjson.loads(self.buffer[self.pos:match.end()])
        except orjson.JSONDecodeError:
            return None
        self.pos = match.end()
        return value

    def _members(self, where: str) -> Iterator[str]:
        """Keys of the object starting here; the caller decodes each value."""
        self._expect("{", f"'{{' to open {where}")
        if self._skip_whitespace() == "}":
            self.pos += 1
            return
        while True:
            if self._skip_whitespace() != '"':
                raise self._error(f"expected a string key in {where}")
            simple = _SIMPLE_STRING.match(self.buffer, self.pos)  # most keys: no escapes, no chunk cut
            if simple is not None:
                key, self.pos = simple.group(1), simple.end()
            else:
                key = self.value()
            self._expect(":", "':' after a key")
            yield key
            if self._expect(",}", f"',' or '}}' in {where}") == "}":
                return

    def object_keys(self) -> Iterator[str]:
        """Keys of the top-level object (each once), then checks nothing follows it; the
        caller decodes each value (:meth:`value`, :meth:`object_items`) before the next key."""
        seen: set[str] = set()
        for key in self._members("the top-level object"):
            if key in seen:
                raise DataFormatError(self.path, "field given twice", field=key)
            seen.add(key)
            yield key
        if self._skip_whitespace():
            raise self._error("extra data after the top-level object")

    def object_items(self, where: str) -> Iterator[tuple[str, Any]]:
        """(key, decoded value) of the object that is the next value; ``where`` names it in
        messages."""
        for key in self._members(f"'{where}'"):
            yield key, self.value()
