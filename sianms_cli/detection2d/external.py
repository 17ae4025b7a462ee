"""External 2D detections read from a file, from any detector.

Schema (one row per detection), Parquet or JSON:

| field | type | meaning |
|---|---|---|
| ``sample_data_token`` | string | the camera sample_data (image) the detection is in |
| ``x1``, ``y1``, ``x2``, ``y2`` | float | box in pixels of the original image, ``x1 < x2``, ``y1 < y2`` |
| ``score`` | float | confidence in [0, 1] |
| ``class`` | string | a nuScenes detection class (``car``, ``pedestrian``, ``bicycle``, ...) |

A box may reach past the image's border, not lie wholly beyond it.
JSON is either a list of such objects or ``{"detections": [...]}``. Rows of classes that
are not being prepared are ignored; every token must be a camera sample_data of the
dataset (checked when the file is loaded, before anything is written).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from sianms_cli.detection2d.detections import Detections2D, GroundTruth2D
from sianms_cli.errors import DataFormatError
from sianms_cli.io import check_regular_file, read_json
from sianms_cli.json_stream import fits_float, is_number
from sianms_cli.nuscenes.classes import DETECTION_CLASSES
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.tables import NUL

FIELDS = ("sample_data_token", "x1", "y1", "x2", "y2", "score", "class")


class ExternalDetections:
    """Detections of a file, grouped by sample_data token and validated against a dataset."""

    def __init__(self, path: str | Path, db: NuScenesDB, classes: tuple[str, ...]) -> None:
        self.path = Path(path)
        columns = _read_columns(self.path)
        tokens = columns["sample_data_token"]
        boxes = np.stack([columns[name] for name in ("x1", "y1", "x2", "y2")], axis=1).reshape(-1, 4)
        scores = columns["score"]
        names = columns["class"]
        bad = ~np.isfinite(boxes).all(axis=1) | ~np.isfinite(scores)
        _reject(self.path, tokens, bad, "x1/y1/x2/y2/score", "values must be finite numbers")
        _reject(self.path, tokens, (boxes[:, 2] <= boxes[:, 0]) | (boxes[:, 3] <= boxes[:, 1]),
                "x1/y1/x2/y2", "box must have x1 < x2 and y1 < y2")
        _reject(self.path, tokens, (scores < 0) | (scores > 1), "score", "must lie in [0, 1]")
        _reject(self.path, tokens, ~np.isin(names, DETECTION_CLASSES), "class",
                f"unknown class; expected one of {', '.join(DETECTION_CLASSES)}")
        rows = db.table("sample_data").indices(tokens, allow_missing=True)
        _reject(self.path, tokens, rows < 0, "sample_data_token", "no such sample_data in "
                f"{db.table_root}")
        modalities = db.sample_data_modalities()[rows] if len(rows) else np.zeros(0, dtype=str)
        _reject(self.path, tokens, modalities != "camera", "sample_data_token",
                "is not a camera image")
        sample_data = db.table("sample_data")
        width, height = (sample_data.column(name)[rows].astype(np.float64) for name in ("width", "height"))
        _reject(self.path, tokens, (boxes[:, 2] <= 0) | (boxes[:, 3] <= 0) | (boxes[:, 0] >= width)
                | (boxes[:, 1] >= height), "x1/y1/x2/y2", "box lies wholly outside its image")
        # A box may reach past the border, as a detector's does, but not by more than the image
        # itself: ROI Align samples a box's whole extent (1e9 px asked for 1e17 bytes), and the
        # cache stores float32 (1e308 became inf).
        _reject(self.path, tokens, (boxes[:, 0] < -width) | (boxes[:, 1] < -height) | (boxes[:, 2] > 2 * width)
                | (boxes[:, 3] > 2 * height), "x1/y1/x2/y2", "box reaches more than its image's size past the image")
        keep = np.isin(names, classes)
        tokens, boxes, scores, names = tokens[keep], boxes[keep], scores[keep], names[keep]
        order = np.argsort(tokens, kind="stable")
        self._tokens = tokens[order]
        self._boxes = boxes[order]
        self._scores = scores[order]
        self._classes = names[order]
        self.count = len(self._tokens)

    def detections(self, sample_data_token: str, ground_truth: GroundTruth2D, image_size: tuple[int, int],
                   rng: np.random.Generator) -> Detections2D:
        """The file's detections of one image, sorted by descending score (possibly none).

        A :class:`~sianms_cli.detection2d.detectors.Detector`: the ground truth, image size and
        generator play no part.
        """
        lo = np.searchsorted(self._tokens, sample_data_token, side="left")
        hi = np.searchsorted(self._tokens, sample_data_token, side="right")
        return Detections2D(self._boxes[lo:hi].copy(), self._scores[lo:hi].copy(),
                            self._classes[lo:hi].copy()).sorted_by_score()


def _reject(path: Path, tokens: np.ndarray, bad: np.ndarray, field: str, message: str) -> None:
    if np.any(bad):
        first = int(np.flatnonzero(bad)[0])
        raise DataFormatError(path, f"row {first}: {message}", token=str(tokens[first]), field=field)


def _read_columns(path: Path) -> dict[str, np.ndarray]:
    if not path.exists():
        raise DataFormatError(path, "detections file not found")
    check_regular_file(path)  # a FIFO or a device would be read until memory runs out
    if path.suffix.lower() == ".parquet":
        try:
            table = pq.read_table(path)
        except (pa.ArrowException, OSError) as error:
            raise DataFormatError(path, f"not a readable Parquet file ({error})") from None
        missing = [name for name in FIELDS if name not in table.column_names]
        if missing:
            raise DataFormatError(path, f"missing column(s) {', '.join(missing)}; expected {', '.join(FIELDS)}",
                                  field=missing[0])
        records = {name: table.column(name).to_pylist() for name in FIELDS}
    elif path.suffix.lower() == ".json":
        data = read_json(path)
        if isinstance(data, dict):
            data = data.get("detections")
        if not isinstance(data, list):
            raise DataFormatError(path, 'expected a list of detections or {"detections": [...]}')
        for i, item in enumerate(data):
            if not isinstance(item, dict):
                raise DataFormatError(path, f"row {i}: expected an object", field="detections")
            missing = [name for name in FIELDS if name not in item]
            if missing:
                raise DataFormatError(path, f"row {i}: missing field", field=missing[0],
                                      token=str(item.get("sample_data_token", "")) or None)
        records = {name: [item[name] for item in data] for name in FIELDS}
    else:
        raise DataFormatError(path, "detections file must end in .parquet or .json")
    out: dict[str, np.ndarray] = {}
    for name in FIELDS:
        values = records[name]
        if name in ("sample_data_token", "class"):
            # numpy's string arrays drop trailing NULs: "car\x00" would be read as "car"
            if not all(isinstance(v, str) and NUL not in v for v in values):
                first = next(i for i, v in enumerate(values) if not (isinstance(v, str) and NUL not in v))
                raise DataFormatError(path, f"row {first}: expected a string without NUL", field=name)
            out[name] = np.array(values, dtype=str) if values else np.zeros(0, dtype="<U1")
        else:
            if not (all(is_number(v) for v in values) and fits_float(values)):
                first = next(i for i, v in enumerate(values) if not (is_number(v) and fits_float([v])))
                raise DataFormatError(path, f"row {first}: expected a number a float can hold", field=name)
            out[name] = np.array(values, dtype=np.float64)
    return out
