"""Detection results files (the nuScenes submission format): read, validate, write.

The format (docs/metrics.md#results-files)::

    {"meta": {"use_camera": bool, "use_lidar": bool, "use_radar": bool, "use_map": bool,
              "use_external": bool},
     "results": {sample_token: [box, ...], ...}}
    box = {"sample_token": str, "translation": [x, y, z], "size": [w, l, h],
           "rotation": [w, x, y, z], "velocity": [vx, vy], "detection_name": str,
           "detection_score": float, "attribute_name": str}

everything in the global frame, metres, m/s. Reading is stricter than the devkit, so that a
file that reads here evaluates there; one :class:`ResultsFormatError` names the file, the
sample token, the box index (0-based within the sample's list) and the field. Whether every
sample of a split is present is checked by the evaluation
(:func:`sianms_cli.metrics.evaluate.align_results`). Files are read in chunks and decoded
one sample at a time (:class:`~sianms_cli.json_stream.JsonStream`), so memory stays near the
size of the boxes as arrays. Files of ``SCAN_MIN_BYTES`` and more are first read by the
compiled scanner of :mod:`~sianms_cli.metrics.results_scan`; whatever it does not accept is
read here, which names the problem.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from itertools import chain, repeat
from operator import itemgetter
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from sianms_cli.errors import DataFormatError, quote
from sianms_cli.metrics.boxes import (
    ATTRIBUTE,
    ATTRIBUTE_NAMES,
    BOX_DTYPE,
    DETECTION_NAMES,
    LABEL,
    NO_ATTRIBUTE,
    empty_boxes,
)
from sianms_cli.io import atomic_file, check_writable_output
from sianms_cli.json_stream import JsonStream, collector_paused, fits_float, is_number, json_kind, types_within

QUATERNION_TOLERANCE = 1e-2
"""A rotation is accepted when | ||q|| - 1 | <= this (it is normalised before use)."""

MAX_BOXES_PER_SAMPLE = 500
META_FLAGS = ("use_camera", "use_lidar", "use_radar", "use_map", "use_external")
BOX_KEYS = ("sample_token", "translation", "size", "rotation", "velocity",
            "detection_name", "detection_score", "attribute_name")
_VECTORS = {"translation": 3, "size": 3, "rotation": 4, "velocity": 2}
_ATTRIBUTE_CODES = {"": NO_ATTRIBUTE, **ATTRIBUTE}
_GETTERS = tuple(itemgetter(key) for key in BOX_KEYS)
_CHUNK_CHARS = 1 << 23  # characters read at a time
SCAN_MIN_BYTES = 64 << 20
"""Files at least this large are first read by the compiled scanner
(:mod:`~sianms_cli.metrics.results_scan`); below, loading it costs more than it saves."""
_BATCH_BOXES = 1 << 13  # boxes decoded, then converted to arrays, at a time


class ResultsFormatError(DataFormatError):
    """A results file (or in-memory results) breaks the format; ``box_index`` is the 0-based
    position of the offending box in its sample's list, or None for a sample-level problem."""

    def __init__(self, path: str | Path, message: str, *, token: str | None = None,
                 field: str | None = None, box_index: int | None = None) -> None:
        self.box_index = box_index
        if box_index is not None:
            message = f"box {box_index}: {message}"
        super().__init__(path, message, token=token, field=field)


@dataclass(frozen=True, eq=False)
class Results:
    """Detection results in memory.

    Attributes:
        sample_tokens: the samples, in file (results-object) order.
        boxes: box table (:data:`~sianms_cli.metrics.boxes.BOX_DTYPE`); ``sample`` indexes
            ``sample_tokens``; rows grouped by sample in that order, list order within a sample
            (the devkit's flattened order).
        meta: the ``meta`` object.
        path: where it was read from (for messages); ``"<results>"`` when built in memory.
        validated: :func:`read_results` checked every value already, so the evaluation only
            checks the per-sample limit of its configuration.
    """

    sample_tokens: tuple[str, ...]
    boxes: np.ndarray
    meta: dict = field(default_factory=lambda: {flag: False for flag in META_FLAGS})
    path: str = "<results>"
    validated: bool = field(default=False, repr=False)

    def sample_bounds(self) -> np.ndarray:
        """(S + 1,) int64: the boxes of sample i are rows bounds[i]:bounds[i + 1]."""
        counts = np.bincount(self.boxes["sample"], minlength=len(self.sample_tokens))
        return np.r_[0, np.cumsum(counts)].astype(np.int64)


# --------------------------------------------------------------------------- validation


def validate_results(results: Results, max_boxes_per_sample: int = MAX_BOXES_PER_SAMPLE) -> None:
    """Check box values and counts (the module docstring's rules) on in-memory results.

    Raises ResultsFormatError for the first offending box in file order, naming its sample
    token, box index and field.
    """
    boxes, path = results.boxes, results.path
    if boxes.dtype != BOX_DTYPE:
        raise TypeError(f"boxes must have BOX_DTYPE, got {boxes.dtype}")
    samples = boxes["sample"]
    if len(boxes) and (samples.min() < 0 or samples.max() >= len(results.sample_tokens)
                       or (np.diff(samples) < 0).any()):
        raise ValueError("box 'sample' indices must index sample_tokens and be grouped in its order")
    bounds = check_samples(results, max_boxes_per_sample)
    bad = first_bad_row(boxes)
    if bad is not None:
        row, name, message = bad
        sample = int(samples[row])
        raise ResultsFormatError(path, message, token=results.sample_tokens[sample], field=name,
                                 box_index=row - int(bounds[sample]))


def check_samples(results: Results, max_boxes_per_sample: int) -> np.ndarray:
    """Raise ResultsFormatError for the first sample listed twice, then for the first with more
    boxes than allowed; returns :meth:`Results.sample_bounds`."""
    if len(set(results.sample_tokens)) != len(results.sample_tokens):
        seen: set[str] = set()
        for token in results.sample_tokens:
            if token in seen:
                raise ResultsFormatError(results.path, "sample listed twice", token=token, field="results")
            seen.add(token)
    return check_box_counts(results, max_boxes_per_sample)


def check_box_counts(results: Results, max_boxes_per_sample: int) -> np.ndarray:
    """Raise ResultsFormatError for the first sample with more boxes than allowed; returns
    :meth:`Results.sample_bounds`."""
    bounds = results.sample_bounds()
    counts = np.diff(bounds)
    if (counts > max_boxes_per_sample).any():
        sample = int(np.flatnonzero(counts > max_boxes_per_sample)[0])
        raise ResultsFormatError(results.path, f"{counts[sample]} boxes; at most {max_boxes_per_sample} per sample",
                                 token=results.sample_tokens[sample], field="results")
    return bounds


def first_bad_row(boxes: np.ndarray, chunk: int = 1 << 18) -> tuple[int, str, str] | None:
    """(row, field, message) of the first box breaking a value rule, first failing field.

    Checked in chunks of rows (views), so the temporaries stay small.
    """
    for start in range(0, len(boxes), chunk):
        checks = _value_checks(boxes[start:start + chunk])
        bad = np.zeros(min(chunk, len(boxes) - start), dtype=bool)
        for _, mask, _ in checks:
            bad |= mask
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            name, _, describe = next(check for check in checks if check[1][row])
            return start + row, name, describe(row)
    return None


def _value_checks(boxes: np.ndarray) -> list[tuple[str, np.ndarray, Callable[[int], str]]]:
    """(field, (N,) bool offending, message for a row) in field order."""
    translation, size, rotation = boxes["translation"], boxes["size"], boxes["rotation"]
    velocity, score = boxes["velocity"], boxes["score"]
    with np.errstate(invalid="ignore", over="ignore"):
        norm = np.sqrt((rotation ** 2).sum(axis=1))
        return [
            ("translation", ~np.isfinite(translation).all(axis=1),
             lambda r: f"must be 3 finite numbers, got {translation[r].tolist()}"),
            ("size", ~(np.isfinite(size) & (size > 0)).all(axis=1),
             lambda r: f"must be 3 positive numbers (w, l, h), got {size[r].tolist()}"),
            ("rotation", ~(np.isfinite(rotation).all(axis=1) & (np.abs(norm - 1) <= QUATERNION_TOLERANCE)),
             lambda r: f"must be a unit quaternion (w, x, y, z) within {QUATERNION_TOLERANCE}, "
                       f"got {rotation[r].tolist()} (norm {norm[r]:.6g})"),
            ("velocity", np.isinf(velocity).any(axis=1),
             lambda r: f"must be 2 finite numbers or NaN, got {velocity[r].tolist()}"),
            ("detection_name", (boxes["label"] < 0) | (boxes["label"] >= len(DETECTION_NAMES)),
             lambda r: f"unknown class index {boxes['label'][r]}"),
            ("detection_score", ~(np.isfinite(score) & (score >= 0) & (score <= 1)),
             lambda r: f"must be a number in [0, 1], got {score[r].item()!r}"),
            ("attribute_name", (boxes["attribute"] < NO_ATTRIBUTE) | (boxes["attribute"] >= len(ATTRIBUTE_NAMES)),
             lambda r: f"unknown attribute index {boxes['attribute'][r]}"),
        ]


# --------------------------------------------------------------------------- reading


def read_results(path: str | Path, *, max_boxes_per_sample: int = MAX_BOXES_PER_SAMPLE,
                 progress: Callable[[int], None] | None = None) -> Results:
    """Read and validate a results file.

    The rules (docs/metrics.md#results-files): the top level is an object with ``results`` (an
    object of lists) and ``meta`` (an object; its ``use_*`` flags, where present, booleans); a
    sample token appears once, with at most ``max_boxes_per_sample`` boxes; every box has the 8
    keys (others are ignored) and its ``sample_token`` equals the sample's key; translation,
    size and rotation are finite JSON numbers, every size > 0, the rotation a unit quaternion
    within ``QUATERNION_TOLERANCE``; velocity two numbers, each finite or NaN; the score finite
    in [0, 1]; ``detection_name`` one of the 10 classes, ``attribute_name`` one of the 8
    attributes or ``""``.

    Args:
        path: the JSON file.
        max_boxes_per_sample: the per-sample limit (the configuration's).
        progress: called with the number of characters read since the last call.

    Raises:
        ResultsFormatError (a DataFormatError): the first problem, naming the file, sample
        token, box index and field; DataFormatError for a missing file or invalid JSON.
    """
    path = Path(path)
    if path.is_dir():
        raise DataFormatError(path, "is a folder, not a results file")
    if not path.is_file():
        raise DataFormatError(path, "not a regular file, not a results file" if path.exists() else
                              "results file not found")
    if path.stat().st_size >= SCAN_MIN_BYTES:
        counted = _CountedProgress(progress)
        scanned = _read_scanned(path, max_boxes_per_sample, counted)
        if scanned is not None:
            return scanned
        progress = counted.skipping()  # the exact reader reads the file again from its start
    tokens: list[str] = []
    seen: set[str] = set()
    batch = _Batch(path)
    parts: list[np.ndarray] = []
    meta: Any = None
    has_results = False
    # Decoding makes millions of box dicts and lists, none in a cycle: without the pause the
    # collector rescans them over and over (bench/results_reader.py shows the cost).
    with collector_paused(), JsonStream(path, chunk_chars=_CHUNK_CHARS, progress=progress) as stream:
        for key in stream.object_keys():
            if key == "results":
                has_results = True
                for token, boxes in stream.object_items("results"):
                    problem = _sample_problem(token, boxes, seen, max_boxes_per_sample)
                    if problem is not None:
                        parts.append(batch.flush())  # an earlier bad box is reported first
                        raise ResultsFormatError(path, problem, token=token, field="results")
                    seen.add(token)
                    batch.add(len(tokens), token, boxes)
                    tokens.append(token)
                    if batch.size >= _BATCH_BOXES:
                        parts.append(batch.flush())
            elif key == "meta":
                meta = stream.value()
            else:
                stream.value()  # other top-level fields are ignored, as by the devkit
    parts.append(batch.flush())
    if not has_results:
        raise DataFormatError(path, "no 'results' object", field="results")
    _check_meta(path, meta)
    # Values were checked batch by batch, counts and duplicates sample by sample.
    return Results(tuple(tokens), np.concatenate(parts), meta, str(path), validated=True)


def _read_scanned(path: Path, max_boxes_per_sample: int, progress: Callable[[int], None]) -> Results | None:
    """The file read by the compiled scanner, or None when it is not in the plain form or
    breaks a rule: the exact reader then names the problem."""
    from sianms_cli.metrics.results_scan import read_plain_results  # loads numba

    plain = read_plain_results(path, progress)  # every box's values checked
    if plain is None or not isinstance(plain.meta, dict):  # a meta that is no object: _check_meta refuses it
        return None
    results = Results(plain.sample_tokens, plain.boxes, plain.meta, str(path), validated=True)
    try:
        _check_meta(path, plain.meta)
        check_samples(results, max_boxes_per_sample)
    except DataFormatError:
        return None
    return results


class _CountedProgress:
    """A progress callback that counts what it reported, so a second reading of the same file
    can skip that much and the total stays the file's size."""

    def __init__(self, progress: Callable[[int], None] | None) -> None:
        self.progress = progress
        self.reported = 0

    def __call__(self, count: int) -> None:
        self.reported += count
        if self.progress is not None:
            self.progress(count)

    def skipping(self) -> Callable[[int], None] | None:
        if self.progress is None:
            return None
        already, report = self.reported, self.progress

        def report_beyond(count: int) -> None:
            nonlocal already
            beyond = max(0, count - already)
            already = max(0, already - count)
            if beyond:
                report(beyond)
        return report_beyond


def _sample_problem(token: str, boxes: Any, seen: set[str], max_boxes: int) -> str | None:
    if token in seen:
        return "sample listed twice"
    if not isinstance(boxes, list):
        return f"must be a list of boxes, got {json_kind(boxes)}"
    if len(boxes) > max_boxes:
        return f"{len(boxes)} boxes; at most {max_boxes} per sample"
    return None


def _check_meta(path: Path, meta: Any) -> None:
    if meta is None:
        raise DataFormatError(path, "no 'meta' object (the devkit requires it)", field="meta")
    if not isinstance(meta, dict):
        raise DataFormatError(path, f"must be an object, got {json_kind(meta)}", field="meta")
    for flag in META_FLAGS:
        if flag in meta and not isinstance(meta[flag], bool):
            raise DataFormatError(path, f"must be true or false, got {quote(meta[flag])}", field=f"meta.{flag}")
    field = _non_finite_field(meta, "meta")
    if field is not None:  # it is copied into the report, which strict JSON cannot hold it in
        raise DataFormatError(path, "not a finite number (NaN and Infinity are not JSON)", field=field)


def _non_finite_field(value: Any, field: str) -> str | None:
    """The dotted field of the first NaN or infinity in ``value`` (objects and lists, depth first), or None."""
    if isinstance(value, float) and not math.isfinite(value):
        return field
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for key, item in items:
        found = _non_finite_field(item, f"{field}.{key}" if isinstance(key, str) else f"{field}[{key}]")
        if found is not None:
            return found
    return None


class _Batch:
    """Boxes of a few samples, decoded from JSON, converted to a box table in one go."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._clear()

    def _clear(self) -> None:
        self.boxes: list = []
        self.samples: list[tuple[int, str, int]] = []  # (sample index, token, box count)
        self.size = 0

    def add(self, index: int, token: str, boxes: list) -> None:
        self.boxes.extend(boxes)
        self.samples.append((index, token, len(boxes)))
        self.size += len(boxes)

    def flush(self) -> np.ndarray:
        """The batch as a box table; ResultsFormatError for its first box (file order) that
        breaks a type or value rule."""
        table = self._convert()
        if table is None:
            self._diagnose()
            raise AssertionError(f"{self.path}: fast check rejected boxes the exact check accepts")
        bad = first_bad_row(table)
        if bad is not None:
            row, name, message = bad
            token, box_index = self._locate(row)
            raise ResultsFormatError(self.path, message, token=token, field=name, box_index=box_index)
        self._clear()
        return table

    def _locate(self, row: int) -> tuple[str, int]:
        """(sample token, box index) of a row of the batch."""
        for _, token, count in self.samples:
            if row < count:
                return token, row
            row -= count
        raise IndexError(row)

    def _convert(self) -> np.ndarray | None:
        """The box table, or None when some box breaks a type rule."""
        boxes = self.boxes
        table = empty_boxes(len(boxes))
        if not boxes:
            return table
        if not types_within(boxes, (dict,)):
            return None
        try:
            tokens, translation, size, rotation, velocity, names, scores, attributes = (
                list(map(getter, boxes)) for getter in _GETTERS)
        except KeyError:
            return None
        expected = list(chain.from_iterable(repeat(token, count) for _, token, count in self.samples))
        if list(tokens) != expected:
            return None
        for name, values in (("translation", translation), ("size", size), ("rotation", rotation),
                             ("velocity", velocity)):
            array = _numbers(values, _VECTORS[name])
            if array is None:
                return None
            table[name] = array
        if not types_within(scores, (float, int)):
            return None
        try:
            table["score"] = np.fromiter(scores, dtype=np.float64, count=len(scores))
        except OverflowError:
            return None
        if not (types_within(names, (str,)) and types_within(attributes, (str,))):
            return None
        try:
            table["label"] = np.fromiter(map(LABEL.__getitem__, names), dtype=np.int8, count=len(names))
            table["attribute"] = np.fromiter(map(_ATTRIBUTE_CODES.__getitem__, attributes), dtype=np.int8,
                                             count=len(attributes))
        except KeyError:
            return None
        table["sample"] = np.repeat([index for index, _, _ in self.samples],
                                    [count for _, _, count in self.samples])
        return table

    def _diagnose(self) -> None:
        """Raise ResultsFormatError for the first box that breaks a type or value rule."""
        position = 0
        for _, token, count in self.samples:
            for box_index, box in enumerate(self.boxes[position:position + count]):
                problem = _box_problem(box, token)
                if problem is None:
                    single = _Batch(self.path)
                    single.add(0, token, [box])
                    table = single._convert()
                    assert table is not None  # a box _box_problem passes has the types _convert needs
                    bad = first_bad_row(table)
                    problem = None if bad is None else bad[1:]
                if problem is not None:
                    raise ResultsFormatError(self.path, problem[1], token=token, field=problem[0],
                                             box_index=box_index)
            position += count


def _numbers(values: Sequence, length: int) -> np.ndarray | None:
    """(N, length) float64 from lists of JSON numbers, or None if any value is not one."""
    if not types_within(values, (list,)) or not set(map(len, values)) <= {length}:
        return None
    flat = list(chain.from_iterable(values))
    if not types_within(flat, (float, int)):
        return None
    try:
        return np.fromiter(flat, dtype=np.float64, count=len(flat)).reshape(len(values), length)
    except OverflowError:
        return None


def _box_problem(box: Any, token: str) -> tuple[str, str] | None:
    """(field, message) of the first type rule ``box`` breaks, or None."""
    if not isinstance(box, dict):
        return "results", f"must be an object, got {json_kind(box)}"
    for key in BOX_KEYS:
        if key not in box:
            return key, "missing"
    if box["sample_token"] != token:
        return "sample_token", f"is {quote(box['sample_token'])}, not the sample it is listed under"
    for name, length in _VECTORS.items():
        value = box[name]
        if (not isinstance(value, list) or len(value) != length
                or not all(is_number(v) for v in value) or not fits_float(value)):
            return name, f"must be a list of {length} numbers, got {quote(value)}"
    score = box["detection_score"]
    if not is_number(score) or not fits_float([score]):
        return "detection_score", f"must be a number, got {quote(score)}"
    name = box["detection_name"]
    if not isinstance(name, str) or name not in LABEL:
        return "detection_name", f"unknown class {quote(name)}; classes: {', '.join(DETECTION_NAMES)}"
    attribute = box["attribute_name"]
    if not isinstance(attribute, str) or attribute not in _ATTRIBUTE_CODES:
        return "attribute_name", (f"unknown attribute {quote(attribute)}; attributes: "
                                  f"{', '.join(ATTRIBUTE_NAMES)} or \"\"")
    return None


# --------------------------------------------------------------------------- writing


def write_results(path: str | Path, results: Results, *, overwrite: bool = False) -> Path:
    """Write results in the submission format, atomically (temporary file + rename).

    Validates first (nothing is written on failure) and refuses to replace an existing file
    unless ``overwrite``. Floats are written with Python's shortest exact repr; a NaN velocity
    is written as ``NaN`` (as Python's json module and the devkit read and write it).
    """
    path = check_writable_output(path, overwrite=overwrite)
    validate_results(results)
    boxes = results.boxes
    bounds = results.sample_bounds()
    columns = {
        "translation": boxes["translation"].tolist(),
        "size": boxes["size"].tolist(),
        "rotation": boxes["rotation"].tolist(),
        "velocity": boxes["velocity"].tolist(),
        "detection_name": [DETECTION_NAMES[k] for k in boxes["label"].tolist()],
        "detection_score": boxes["score"].tolist(),
        "attribute_name": [ATTRIBUTE_NAMES[k] if k >= 0 else "" for k in boxes["attribute"].tolist()],
    }
    with atomic_file(path, text=True) as out:
        out.write('{"meta": ' + json.dumps(results.meta) + ', "results": {')
        for i, token in enumerate(results.sample_tokens):
            entries = [
                {"sample_token": token, **{name: values[row] for name, values in columns.items()}}
                for row in range(bounds[i], bounds[i + 1])
            ]
            out.write(("" if i == 0 else ", ") + json.dumps(token) + ": " + json.dumps(entries))
        out.write("}}\n")
    return path


def results_from_boxes(sample_tokens: Sequence[str], boxes: np.ndarray, meta: dict | None = None,
                       path: str = "<results>") -> Results:
    """Results from a box table whose ``sample`` indexes ``sample_tokens``: rows are grouped by
    sample (stable, so list order within a sample is kept)."""
    order = np.argsort(boxes["sample"], kind="stable")
    meta = {flag: False for flag in META_FLAGS} if meta is None else meta
    return Results(tuple(sample_tokens), boxes[order], meta, path)
