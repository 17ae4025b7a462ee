"""A compiled fast path for large results files in their plain form.

:func:`~sianms_cli.metrics.results.read_results` decodes with orjson, which builds a Python
dict, 5 lists, 13 floats and 4 strings per box and then copies them into arrays. This module
reads such a file without a Python object per box: a numba scanner walks the bytes once,
checks the grammar, codes the class and attribute names and writes an Arrow string view of
every number's text (no copy of the file); pyarrow converts the views (its string-to-double
cast is correctly rounded, so every value is the one Python's ``float`` gives). Two threads
share the work (the scanner and the cast release the GIL): one reads from the start, the other
from a box list's end guessed near the middle of the file, and its work is kept only if the
first thread's last sample ends exactly there. bench/results_reader.py times it.

The scanner accepts only the plain form the common toolkits write: ``meta`` (a flat object),
then ``results``, and nothing else; every box has exactly the 8 keys, once each, in any order;
ASCII strings without escapes; numbers of at most 40 characters (no NaN). Anything else, and
any file that breaks a rule of the format, makes :func:`read_plain_results` return None, and
the exact reader reads the file and names the problem: this path changes how fast a file is
read, never whether it is accepted, what its table holds, or what an error says.
"""

from __future__ import annotations

import mmap
import re
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable, NamedTuple

import numba
import numpy as np
import orjson
import pyarrow as pa
import pyarrow.compute as pc

from sianms_cli.metrics.boxes import ATTRIBUTE_NAMES, DETECTION_NAMES, NO_ATTRIBUTE, empty_boxes
from sianms_cli.metrics.results import BOX_KEYS, first_bad_row

_NUMBERS = {"translation": (0, 3), "size": (3, 3), "rotation": (6, 4), "velocity": (10, 2),
            "detection_score": (12, 1)}
"""(first slot, count) of each numeric key among a box's numbers."""
NUMBERS_PER_BOX = sum(count for _, count in _NUMBERS.values())
_SAMPLE_TOKEN, _SCORE, _NAME = map(BOX_KEYS.index, ("sample_token", "detection_score", "detection_name"))
"""Codes of keys in the scanner: a key's index in BOX_KEYS (the other string key is
attribute_name)."""
MAX_NUMBER_BYTES = 40
BOXES_PER_CHUNK = 1 << 16
_MAX_VIEW_OFFSET = (1 << 31) - 1  # views hold int32 offsets

_DONE, _MORE, _REFUSED = 0, 1, 2

# The bytes of JSON's grammar, as the scanner compares them.
_QUOTE, _COMMA, _COLON, _MINUS, _PLUS, _POINT = b'",:-+.'
_OPEN_OBJECT, _CLOSE_OBJECT, _OPEN_LIST, _CLOSE_LIST = b"{}[]"
_ZERO, _ONE, _NINE, _EXPONENT, _EXPONENT_UPPER = b"019eE"
_SPACE, _NEWLINE, _RETURN, _TAB = b" \n\r\t"
_TRUE, _NULL, _FALSE = tuple(b"true"), tuple(b"null"), tuple(b"false")

_PLAIN, _STRING_END, _NOT_PLAIN = 0, 1, 2
_STRING_BYTE = np.full(256, _PLAIN, dtype=np.uint8)
"""What each byte is within a string: plain, the closing quote, or what the plain form refuses
(control characters, the backslash of an escape, non-ASCII bytes)."""
_STRING_BYTE[:32] = _STRING_BYTE[128:] = _STRING_BYTE[ord("\\")] = _NOT_PLAIN
_STRING_BYTE[ord('"')] = _STRING_END


def _table(names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Names as a zero-padded (N, width) uint8 table and their lengths, for the scanner."""
    width = max(map(len, names))
    table = np.zeros((len(names), width), dtype=np.uint8)
    for row, name in enumerate(names):
        table[row, :len(name)] = np.frombuffer(name.encode("ascii"), dtype=np.uint8)
    return table, np.array([len(name) for name in names], dtype=np.int64)


_KEYS = _table(BOX_KEYS)
_CLASSES = _table(DETECTION_NAMES)
_ATTRIBUTES = _table(ATTRIBUTE_NAMES + ("",))  # the last row codes as NO_ATTRIBUTE
_HEAD = _table(('"meta"', '"results"'))
_SLOTS = np.array([_NUMBERS.get(key, (-1, 0)) for key in BOX_KEYS], dtype=np.int64)  # (-1, 0): a string key


class _Chunk(NamedTuple):
    """What one scanner call found: samples, their boxes, and views of their numbers' text."""

    keys: np.ndarray  # (S, 2) byte bounds of each sample token
    box_sample: np.ndarray  # (B,) sample, 0-based within the chunk
    box_label: np.ndarray
    box_attribute: np.ndarray
    number_views: np.ndarray  # (B, 13, 16) uint8: Arrow string views of the numbers' text


# --------------------------------------------------------------------------- the scanner


@numba.njit(cache=True)
def _at(buf, i):
    """buf[i], or 0 past the end (0 is never valid JSON outside a string)."""
    if i < len(buf):
        return np.int64(buf[i])
    return np.int64(0)


@numba.njit(cache=True)
def _space(buf, i):
    while i < len(buf) and (buf[i] == _SPACE or buf[i] == _NEWLINE or buf[i] == _RETURN or buf[i] == _TAB):
        i += 1
    return i


@numba.njit(cache=True)
def _string_end(buf, i):
    """Index after the string opening at ``i``; -1 unless it is plain ASCII (no escape, no
    control character)."""
    if _at(buf, i) != _QUOTE:
        return -1
    i += 1
    while i < len(buf):
        kind = _STRING_BYTE[buf[i]]
        if kind != _PLAIN:
            return i + 1 if kind == _STRING_END else -1
        i += 1
    return -1


@numba.njit(cache=True)
def _digits_end(buf, i):
    while _ZERO <= _at(buf, i) <= _NINE:
        i += 1
    return i


@numba.njit(cache=True)
def _number_end(buf, i):
    """Index after the JSON number starting at ``i``; -1 if there is none or it is too long."""
    start = i
    if _at(buf, i) == _MINUS:
        i += 1
    if _at(buf, i) == _ZERO:
        i += 1
    elif _ONE <= _at(buf, i) <= _NINE:
        i = _digits_end(buf, i)
    else:
        return -1
    if _at(buf, i) == _POINT:
        end = _digits_end(buf, i + 1)
        if end == i + 1:
            return -1
        i = end
    if _at(buf, i) == _EXPONENT or _at(buf, i) == _EXPONENT_UPPER:
        i += 1
        if _at(buf, i) == _PLUS or _at(buf, i) == _MINUS:
            i += 1
        end = _digits_end(buf, i)
        if end == i:
            return -1
        i = end
    return i if i - start <= MAX_NUMBER_BYTES else -1


@numba.njit(cache=True)
def _find(buf, start, end, table, lengths):
    """Row of ``table`` equal to ``buf[start:end]``, or -1."""
    for row in range(len(lengths)):
        if lengths[row] == end - start and _same(buf, start, table[row], lengths[row]):
            return row
    return -1


@numba.njit(cache=True)
def _quoted(buf, i, table, lengths):
    """Row of ``table`` whose text, in quotes, starts at ``i``, or -1."""
    if _at(buf, i) != _QUOTE:
        return -1
    for row in range(len(lengths)):
        if _at(buf, i + 1 + lengths[row]) == _QUOTE and _same(buf, i + 1, table[row], lengths[row]):
            return row
    return -1


@numba.njit(cache=True)
def _same(buf, start, text, length):
    """Whether buf[start:start + length] equals text[:length] (start + length < len(buf))."""
    for k in range(length):
        if buf[start + k] != text[k]:
            return False
    return True


@numba.njit(cache=True)
def _box_end(buf, i, base, box, token_start, token_end, keys, key_lengths, classes, class_lengths,
             attributes, attribute_lengths, slots, box_label, box_attribute, number_views):
    """Scan the box object at ``i``; index after it, or -1 if it is not a plain box.

    Writes the box's class, attribute and the views of its 13 numbers (into ``buf[base:]``).
    """
    if _at(buf, i) != _OPEN_OBJECT:
        return -1
    i = _space(buf, i + 1)
    seen = 0
    while True:
        key = _quoted(buf, i, keys, key_lengths)
        if key < 0 or seen & (1 << key):
            return -1
        seen |= 1 << key
        i = _space(buf, i + key_lengths[key] + 2)
        if _at(buf, i) != _COLON:
            return -1
        i = _space(buf, i + 1)
        first, width = slots[key, 0], slots[key, 1]
        if first >= 0:
            vector = key != _SCORE
            if vector:
                if _at(buf, i) != _OPEN_LIST:
                    return -1
                i = _space(buf, i + 1)
            for k in range(width):
                end = _number_end(buf, i)
                if end < 0 or end - base > _MAX_VIEW_OFFSET:
                    return -1
                # JSON's -0 is the integer 0 (Python reads 0, not -0.0): view it without its sign
                negative_zero = end - i == 2 and buf[i] == _MINUS and buf[i + 1] == _ZERO
                _write_view(number_views, box, first + k, buf, i + negative_zero, end, base)
                i = _space(buf, end)
                if vector:
                    if _at(buf, i) != (_COMMA if k < width - 1 else _CLOSE_LIST):
                        return -1
                    i = _space(buf, i + 1)
        elif key == _SAMPLE_TOKEN:
            length = token_end - token_start
            if (_at(buf, i) != _QUOTE or _at(buf, i + 1 + length) != _QUOTE
                    or not _same(buf, i + 1, buf[token_start:token_end], length)):
                return -1
            i = _space(buf, i + length + 2)
        elif key == _NAME:
            label = _quoted(buf, i, classes, class_lengths)
            if label < 0:
                return -1
            box_label[box] = label
            i = _space(buf, i + class_lengths[label] + 2)
        else:
            code = _quoted(buf, i, attributes, attribute_lengths)
            if code < 0:
                return -1
            box_attribute[box] = NO_ATTRIBUTE if code == len(attribute_lengths) - 1 else code
            i = _space(buf, i + attribute_lengths[code] + 2)
        if _at(buf, i) == _CLOSE_OBJECT:
            return i + 1 if seen == (1 << len(key_lengths)) - 1 else -1
        if _at(buf, i) != _COMMA:
            return -1
        i = _space(buf, i + 1)


@numba.njit(cache=True)
def _write_view(views, box, slot, buf, start, end, base):
    """Write views[box, slot], the Arrow string view (16 bytes, little-endian) of
    ``buf[start:end]``, whose data buffer starts at ``buf[base]``: the length, then the text
    itself when it fits in 12 bytes, else its first 4 bytes, buffer 0 and its offset."""
    length = end - start
    views[box, slot, 0] = length  # at most MAX_NUMBER_BYTES
    for k in range(1, 4):
        views[box, slot, k] = 0
    inline = min(length, 12)
    for k in range(inline):
        views[box, slot, 4 + k] = buf[start + k]
    for k in range(inline, 12):
        views[box, slot, 4 + k] = 0
    if length > 12:
        offset = start - base
        for k in range(4):
            views[box, slot, 8 + k] = 0
            views[box, slot, 12 + k] = (offset >> (8 * k)) & 255


@numba.njit(cache=True, nogil=True)
def _scan_members(buf, i, opening, stop, keys, key_lengths, classes, class_lengths, attributes,
                  attribute_lengths, slots, sample_keys, box_sample, box_label, box_attribute,
                  number_views):
    """Scan members of the ``results`` object until it closes, the outputs are full or a
    member ends at or beyond ``stop``.

    ``i`` is at the object's ``{`` when ``opening``, else just after a member. Returns
    (status, index, opening, samples, boxes): _DONE with the index after the closing ``}``;
    _MORE with where to go on (after the last whole member); _REFUSED when the text is not
    the plain form.
    """
    samples = boxes = 0
    base = i  # the numbers' views point into buf[base:]
    resume, resume_opening = i, opening
    if opening:
        if _at(buf, i) != _OPEN_OBJECT:
            return _REFUSED, i, opening, 0, 0
        i = _space(buf, i + 1)
        if _at(buf, i) == _CLOSE_OBJECT:
            return _DONE, i + 1, False, 0, 0
    else:
        i = _space(buf, i)
        if _at(buf, i) == _CLOSE_OBJECT:
            return _DONE, i + 1, False, 0, 0
        if _at(buf, i) != _COMMA:
            return _REFUSED, i, opening, 0, 0
        i = _space(buf, i + 1)
    while True:
        if samples == len(sample_keys):
            return _MORE, resume, resume_opening, samples, boxes
        token_end = _string_end(buf, i)
        if token_end < 0:
            return _REFUSED, i, opening, 0, 0
        token_start = i + 1
        i = _space(buf, token_end)
        if _at(buf, i) != _COLON:
            return _REFUSED, i, opening, 0, 0
        i = _space(buf, i + 1)
        if _at(buf, i) != _OPEN_LIST:
            return _REFUSED, i, opening, 0, 0
        i = _space(buf, i + 1)
        member_boxes = 0
        if _at(buf, i) == _CLOSE_LIST:
            i += 1
        else:
            while True:
                box = boxes + member_boxes
                if box == len(box_sample) or i - base > _MAX_VIEW_OFFSET // 2:  # a new chunk, a new base
                    return _MORE, resume, resume_opening, samples, boxes
                box_sample[box] = samples
                box_attribute[box] = NO_ATTRIBUTE
                i = _box_end(buf, i, base, box, token_start, token_end - 1, keys, key_lengths, classes,
                             class_lengths, attributes, attribute_lengths, slots, box_label,
                             box_attribute, number_views)
                if i < 0:
                    return _REFUSED, i, opening, 0, 0
                member_boxes += 1
                i = _space(buf, i)
                if _at(buf, i) == _CLOSE_LIST:
                    i += 1
                    break
                if _at(buf, i) != _COMMA:
                    return _REFUSED, i, opening, 0, 0
                i = _space(buf, i + 1)
        sample_keys[samples, 0], sample_keys[samples, 1] = token_start, token_end - 1
        samples += 1
        boxes += member_boxes
        resume, resume_opening = i, False
        if i >= stop:
            return _MORE, resume, resume_opening, samples, boxes
        i = _space(buf, i)
        if _at(buf, i) == _CLOSE_OBJECT:
            return _DONE, i + 1, False, samples, boxes
        if _at(buf, i) != _COMMA:
            return _REFUSED, i, opening, 0, 0
        i = _space(buf, i + 1)


@numba.njit(cache=True)
def _scan_head(buf, names, lengths):
    """(meta start, meta end, index of the ``results`` value) for a file that opens with
    ``{"meta": {flat object}, "results": ``; (-1, -1, -1) otherwise. ``names`` holds
    ``"meta"`` and ``"results"``, quotes included."""
    refused = (-1, -1, -1)
    i = _space(buf, 0)
    if _at(buf, i) != _OPEN_OBJECT:
        return refused
    i = _space(buf, i + 1)
    meta_start = meta_end = -1
    for expected in range(2):
        end = _string_end(buf, i)
        if end < 0 or _find(buf, i, end, names, lengths) != expected:
            return refused
        i = _space(buf, end)
        if _at(buf, i) != _COLON:
            return refused
        i = _space(buf, i + 1)
        if expected == 1:
            return meta_start, meta_end, i
        meta_start = i
        i = _flat_object_end(buf, i)
        if i < 0:
            return refused
        meta_end = i
        i = _space(buf, i)
        if _at(buf, i) != _COMMA:
            return refused
        i = _space(buf, i + 1)
    return refused


@numba.njit(cache=True)
def _flat_object_end(buf, i):
    """Index after an object of plain strings, numbers, true, false or null at ``i``, or -1."""
    if _at(buf, i) != _OPEN_OBJECT:
        return -1
    i = _space(buf, i + 1)
    if _at(buf, i) == _CLOSE_OBJECT:
        return i + 1
    while True:
        i = _string_end(buf, i)
        if i < 0:
            return -1
        i = _space(buf, i)
        if _at(buf, i) != _COLON:
            return -1
        i = _space(buf, i + 1)
        end = _string_end(buf, i)
        if end < 0:
            end = _literal_end(buf, i, _TRUE)
        if end < 0:
            end = _literal_end(buf, i, _NULL)
        if end < 0:
            end = _literal_end(buf, i, _FALSE)
        if end < 0:
            end = _number_end(buf, i)
        i = end
        if i < 0:
            return -1
        i = _space(buf, i)
        if _at(buf, i) == _CLOSE_OBJECT:
            return i + 1
        if _at(buf, i) != _COMMA:
            return -1
        i = _space(buf, i + 1)


@numba.njit(cache=True)
def _literal_end(buf, i, word):
    """Index after ``word`` (a tuple of bytes) if it starts at ``i``, else -1."""
    for k in range(len(word)):
        if _at(buf, i + k) != word[k]:
            return -1
    return i + len(word)


# --------------------------------------------------------------------------- reading


class PlainResults(NamedTuple):
    """A plain results file's content: every box's values checked, the samples (duplicates,
    counts per sample) and the meta not."""

    sample_tokens: tuple[str, ...]
    boxes: np.ndarray
    meta: object


def read_plain_results(path: str | Path, progress: Callable[[int], None] | None = None) -> PlainResults | None:
    """The samples, box table and meta of a results file in the plain form, or None.

    Every box's values are checked (:func:`~sianms_cli.metrics.results.first_bad_row`);
    the samples (duplicates, counts) and the meta are left to the caller. None means the file
    is not in the plain form (see the module docstring) or some box breaks a rule; the caller
    then reads it with the exact reader, which names the problem. Nothing here raises for a
    bad file; OSError passes through.
    """
    with open(path, "rb") as file:
        if file.seek(0, 2) == 0:
            return None
        mapped = mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ)
    try:
        return _read(np.frombuffer(mapped, dtype=np.uint8), mapped, progress)
    finally:
        try:
            mapped.close()
        except BufferError:  # an exception's traceback still holds views; the map goes with them
            pass


def _read(buf: np.ndarray, mapped: mmap.mmap, progress: Callable[[int], None] | None) -> PlainResults | None:
    meta_start, meta_end, position = _scan_head(buf, *_HEAD)
    if position < 0:
        return None
    try:
        meta = orjson.loads(buf[meta_start:meta_end].tobytes())
    except orjson.JSONDecodeError:
        return None
    report = _ThreadSafeProgress(progress)
    report(position)
    # Two threads (the scanner and pyarrow release the GIL): one reads the first half, the
    # other from a member boundary guessed near the middle. The guess holds when the first
    # thread's last member ends exactly there; otherwise the first thread reads on alone.
    middle = _member_boundary_after(buf, (position + len(buf)) // 2)
    with ThreadPoolExecutor(max_workers=2) as threads:
        later: list[int] = []  # the second thread's progress, reported once its start is confirmed
        first = threads.submit(_read_part, buf, mapped, position, True, middle, report)
        second = threads.submit(_read_part, buf, mapped, middle, False, len(buf), later.append) if middle > 0 else None
        parts = [first.result()]
        if parts[0] is not None and parts[0].status == _MORE:
            if second is not None and parts[0].position == middle:  # no second thread: middle is -1
                parts.append(second.result())
                report(sum(later))
            else:
                parts.append(_read_part(buf, mapped, parts[0].position, parts[0].opening, len(buf), report))
    read = [part for part in parts if part is not None]
    if len(read) != len(parts) or read[-1].status != _DONE:
        return None
    if not _only_closing_brace_after(buf, read[-1].position):
        return None
    report(len(buf) - read[-1].position)
    tokens = [token for part in read for token in part.tokens]
    tables = [table for part in read for table in part.tables]
    offset = len(read[0].tokens)
    for table in read[1].tables if len(read) == 2 else ():
        table["sample"] += offset
    return PlainResults(tuple(tokens), _joined(tables), meta)


class _Part(NamedTuple):
    tokens: list[str]
    tables: list[np.ndarray]  # sample indices count from the part's first sample
    status: int  # _DONE: the results object closed; _MORE: the part reached its stop
    position: int
    opening: bool


def _read_part(buf: np.ndarray, mapped: mmap.mmap, position: int, opening: bool, stop: int,
               report: Callable[[int], None]) -> _Part | None:
    """Scan and convert chunk after chunk from ``position`` until the results object closes
    or a member ends at or beyond ``stop``; None if the text is not the plain form."""
    tokens: list[str] = []
    tables: list[np.ndarray] = []
    status = _MORE
    outputs = _empty_chunk()  # reused: touching fresh memory costs more than scanning into it
    while status == _MORE and position < stop:
        start = position
        status, position, opening, samples, boxes = _scan_members(
            buf, position, opening, stop, *_KEYS, *_CLASSES, *_ATTRIBUTES, _SLOTS, *outputs)
        if status == _REFUSED or (status == _MORE and samples == 0):
            return None
        chunk = _Chunk(outputs.keys[:samples], outputs.box_sample[:boxes], outputs.box_label[:boxes],
                       outputs.box_attribute[:boxes], outputs.number_views[:boxes])
        table = _box_table(chunk, len(tokens), buf[start:position])
        if table is None or first_bad_row(table) is not None:
            return None
        tables.append(table)
        tokens.extend(bytes(buf[begin:end]).decode("ascii") for begin, end in chunk.keys.tolist())
        _release(mapped, start, position)
        report(position - start)
    return _Part(tokens, tables, status, position, opening)


_MEMBER_BOUNDARY = re.compile(rb"\}[ \t\n\r]*\]")


def _member_boundary_after(buf: np.ndarray, start: int) -> int:
    """Where the first ``}]`` after ``start`` ends (a box list's end in the plain form,
    unless the text is inside a string: the caller checks), or -1."""
    window = buf[start:start + (1 << 20)].tobytes()
    found = _MEMBER_BOUNDARY.search(window)
    return start + found.end() if found else -1


class _ThreadSafeProgress:
    """A progress callback two threads may call."""

    def __init__(self, progress: Callable[[int], None] | None) -> None:
        self.progress, self.lock = progress, threading.Lock()

    def __call__(self, count: int) -> None:
        if self.progress is not None and count:
            with self.lock:
                self.progress(count)


def _joined(tables: list[np.ndarray]) -> np.ndarray:
    """The tables as one, in an anonymous memory map rather than memory numpy allocates.

    numpy asks the kernel for transparent huge pages on large arrays; where the kernel then
    compacts memory on the first touch (``defrag=madvise``, a common default), filling a
    validation-sized table stalls for a noticeable share of the read (bench/results_reader.py).
    """
    count = sum(map(len, tables))
    if count == 0:
        return np.concatenate(tables)
    joined = np.frombuffer(mmap.mmap(-1, count * tables[0].dtype.itemsize), dtype=tables[0].dtype)
    return np.concatenate(tables, out=joined)


def _only_closing_brace_after(buf: np.ndarray, position: int) -> bool:
    """Whether only the top-level ``}`` and whitespace follow ``position``."""
    position = _space(buf, position)
    return position < len(buf) and buf[position] == _CLOSE_OBJECT and _space(buf, position + 1) == len(buf)


def _empty_chunk() -> _Chunk:
    boxes = BOXES_PER_CHUNK
    return _Chunk(np.empty((boxes, 2), np.int64), np.empty(boxes, np.int32), np.empty(boxes, np.int8),
                  np.empty(boxes, np.int8), np.empty((boxes, NUMBERS_PER_BOX, 16), np.uint8))


def _box_table(chunk: _Chunk, first_sample: int, text: np.ndarray) -> np.ndarray | None:
    """The chunk's box table, its numbers converted from ``text`` (what the views point into)
    by pyarrow; None if a number does not convert."""
    views = pa.Array.from_buffers(pa.string_view(), chunk.number_views.size // 16,
                                  [None, pa.py_buffer(chunk.number_views), pa.py_buffer(text)])
    try:
        numbers = pc.cast(views, pa.float64()).to_numpy().reshape(-1, NUMBERS_PER_BOX)
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError):  # an out-of-range number; an old pyarrow
        return None
    table = empty_boxes(len(chunk.box_sample))
    table["sample"] = chunk.box_sample + first_sample
    table["label"] = chunk.box_label
    table["attribute"] = chunk.box_attribute
    for name in ("translation", "size", "rotation", "velocity"):
        first, width = _NUMBERS[name]
        table[name] = numbers[:, first:first + width]
    table["score"] = numbers[:, _NUMBERS["detection_score"][0]]
    return table


def _release(mapped: mmap.mmap, start: int, end: int) -> None:
    """Drop the pages wholly within [start, end) from this process's memory (the page cache
    keeps them), so the resident set stays near the table's size."""
    start = -(-start // mmap.PAGESIZE) * mmap.PAGESIZE
    end = end // mmap.PAGESIZE * mmap.PAGESIZE
    if end > start and hasattr(mapped, "madvise"):
        mapped.madvise(mmap.MADV_DONTNEED, start, end - start)
