"""Detection evaluation configurations: the devkit's ``detection_cvpr_2019``, the paper's, and
user JSON files with the same fields.

A configuration has the fields of the devkit's ``DetectionConfig`` and serialises to the
same JSON (the ``cfg`` embedded in every metrics output):

- ``class_range``: {detection class: range in metres}; the classes evaluated, in this order,
  and the ego distance (strict ``<``) beyond which their boxes are dropped;
- ``dist_fcn``: ``"center_distance"`` (BEV centre distance; the only one the devkit has);
- ``dist_ths``: matching thresholds in metres; AP is averaged over them;
- ``dist_th_tp``: the threshold whose matches give the TP errors; one of ``dist_ths``;
- ``min_recall``, ``min_precision``: the AP and TP-error integration limits (0.1, 0.1);
- ``max_boxes_per_sample``: the most boxes a results file may hold for one sample (500);
- ``mean_ap_weight``: the weight of mAP in NDS (5).

Unlike the devkit, a configuration may name any subset of the 10 detection classes; mAP,
the mean TP errors and NDS are then taken over those classes only.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from sianms_cli.errors import DataFormatError, SianmsError, quote
from sianms_cli.metrics.boxes import DETECTION_NAMES, LABEL
from sianms_cli.nuscenes.classes import PAPER_CLASSES
from sianms_cli.io import RECORD_MAX_BYTES, expand_home, read_json
from sianms_cli.json_stream import is_finite_number, is_number, json_kind

DETECTION_CVPR_2019: dict[str, Any] = {
    "class_range": {
        "car": 50,
        "truck": 50,
        "bus": 50,
        "trailer": 50,
        "construction_vehicle": 50,
        "pedestrian": 40,
        "motorcycle": 40,
        "bicycle": 40,
        "traffic_cone": 30,
        "barrier": 30,
    },
    "dist_fcn": "center_distance",
    "dist_ths": [0.5, 1.0, 2.0, 4.0],
    "dist_th_tp": 2.0,
    "min_recall": 0.1,
    "min_precision": 0.1,
    "max_boxes_per_sample": 500,
    "mean_ap_weight": 5,
}
"""nuscenes-devkit 1.2.0 ``eval/detection/configs/detection_cvpr_2019.json``, verbatim."""

PAPER: dict[str, Any] = {
    **DETECTION_CVPR_2019,
    "class_range": {name: DETECTION_CVPR_2019["class_range"][name] for name in PAPER_CLASSES},
}
"""The paper's protocol (its §V-A; docs/metrics.md#the-papers-protocol): car, pedestrian and bicycle (its
"cyclist"), with the devkit's ranges, thresholds 0.5/1/2/4 m, TP errors at 2 m."""

PRESETS: dict[str, dict[str, Any]] = {"detection_cvpr_2019": DETECTION_CVPR_2019, "paper": PAPER}

CENTER_DISTANCE = "center_distance"
MAX_DIST_THS = 100  # each threshold is a 101-point curve per class and region; the devkit's have 4


@dataclass(frozen=True, eq=True)
class DetectionConfig:
    """A validated evaluation configuration (see the module docstring for the fields).

    ``name`` says where it came from (a preset name or a file path) and is not serialised.
    Build one with :func:`load_config` or :meth:`from_dict`, which validate.
    """

    class_range: Mapping[str, float]
    dist_ths: tuple[float, ...]
    dist_th_tp: float
    min_recall: float
    min_precision: float
    max_boxes_per_sample: int
    mean_ap_weight: float
    dist_fcn: str = CENTER_DISTANCE
    name: str = "custom"

    @property
    def class_names(self) -> tuple[str, ...]:
        """The evaluated classes, in configuration order."""
        return tuple(self.class_range)

    @property
    def labels(self) -> np.ndarray:
        """(K,) int64 indices of :attr:`class_names` into DETECTION_NAMES."""
        return np.array([LABEL[name] for name in self.class_range], dtype=np.int64)

    def range_by_label(self) -> np.ndarray:
        """(10,) float64 class range per DETECTION_NAMES index; -inf for classes not evaluated
        (so every box of such a class is dropped by the range filter)."""
        ranges = np.full(len(DETECTION_NAMES), -np.inf)
        for name, value in self.class_range.items():
            ranges[LABEL[name]] = float(value)
        return ranges

    def serialize(self) -> dict[str, Any]:
        """The devkit's ``DetectionConfig.serialize()`` layout."""
        return {
            "class_range": dict(self.class_range),
            "dist_fcn": self.dist_fcn,
            "dist_ths": list(self.dist_ths),
            "dist_th_tp": self.dist_th_tp,
            "min_recall": self.min_recall,
            "min_precision": self.min_precision,
            "max_boxes_per_sample": self.max_boxes_per_sample,
            "mean_ap_weight": self.mean_ap_weight,
        }

    @classmethod
    def from_dict(cls, content: Any, *, source: str | Path = "<config>", name: str | None = None,
                  defaults: Mapping[str, Any] = DETECTION_CVPR_2019) -> DetectionConfig:
        """Validate ``content`` (a decoded JSON object); missing fields take ``defaults``.

        Raises DataFormatError naming ``source`` and the offending field.
        """
        if not isinstance(content, dict):
            raise DataFormatError(source, f"a configuration must be a JSON object, got {json_kind(content)}")
        unknown = [key for key in content if key not in DETECTION_CVPR_2019]
        if unknown:
            raise DataFormatError(source, f"unknown field; the fields are {', '.join(DETECTION_CVPR_2019)}",
                                  field=str(unknown[0]))
        merged = {**defaults, **content}
        fail = _failer(source)

        class_range = merged["class_range"]
        if not isinstance(class_range, dict) or not class_range:
            fail("class_range", "must be a non-empty object {class name: range in metres}")
        for cls_name, value in class_range.items():
            if cls_name not in LABEL:
                fail(f"class_range.{cls_name}",
                     f"unknown detection class; known: {', '.join(DETECTION_NAMES)}")
            if not is_finite_number(value) or value <= 0:
                fail(f"class_range.{cls_name}", f"must be a positive number of metres, got {quote(value)}")

        if merged["dist_fcn"] != CENTER_DISTANCE:
            fail("dist_fcn", f"only '{CENTER_DISTANCE}' is supported, got {quote(merged['dist_fcn'])}")

        dist_ths = merged["dist_ths"]
        if (not isinstance(dist_ths, list) or not dist_ths
                or not all(is_finite_number(t) and t > 0 for t in dist_ths)):
            fail("dist_ths", f"must be a non-empty list of positive numbers of metres, got {quote(dist_ths)}")
        if len(set(dist_ths)) != len(dist_ths):
            fail("dist_ths", f"thresholds must be distinct, got {quote(dist_ths)}")
        if len(dist_ths) > MAX_DIST_THS:
            fail("dist_ths", f"at most {MAX_DIST_THS} thresholds (the devkit's: 4), got {len(dist_ths):,}")
        if not is_number(merged["dist_th_tp"]) or merged["dist_th_tp"] not in dist_ths:
            fail("dist_th_tp", f"must be one of dist_ths {quote(dist_ths)}, got {quote(merged['dist_th_tp'])}")
        min_recall, min_precision = merged["min_recall"], merged["min_precision"]
        if not is_finite_number(min_recall) or not 0 <= min_recall <= 1 or round(100 * min_recall) > 99:
            # AP averages the precision at the 1 %-recall points above it: past 0.99 none is left
            fail("min_recall", f"must be a number in [0, 0.99], got {quote(min_recall)}")
        if not is_number(min_precision) or not 0 <= min_precision < 1:
            fail("min_precision", f"must be a number in [0, 1), got {quote(min_precision)}")
        max_boxes = merged["max_boxes_per_sample"]
        if not isinstance(max_boxes, int) or isinstance(max_boxes, bool) or max_boxes < 1:
            fail("max_boxes_per_sample", f"must be a positive integer, got {quote(max_boxes)}")
        weight = merged["mean_ap_weight"]
        if not is_finite_number(weight) or weight < 0:
            fail("mean_ap_weight", f"must be a non-negative number, got {quote(weight)}")

        return cls(
            class_range=dict(class_range),
            dist_ths=tuple(dist_ths),
            dist_th_tp=merged["dist_th_tp"],
            min_recall=min_recall,
            min_precision=min_precision,
            max_boxes_per_sample=max_boxes,
            mean_ap_weight=weight,
            dist_fcn=CENTER_DISTANCE,
            name=str(source) if name is None else name,
        )


def load_config(spec: str | Path | DetectionConfig = "detection_cvpr_2019") -> DetectionConfig:
    """A configuration by preset name (``detection_cvpr_2019``, ``paper``) or JSON file path.

    A file holds an object with any of the devkit's config fields; the fields it leaves out
    take the ``detection_cvpr_2019`` values. Raises DataFormatError naming the file and the
    field for a malformed file, SianmsError for a name that is neither a preset nor a file.
    """
    if isinstance(spec, DetectionConfig):
        return spec
    text = str(spec)
    if text in PRESETS:
        return DetectionConfig.from_dict(PRESETS[text], source=text, name=text)
    path = expand_home(Path(text))  # --config=~/c.json reaches here with its ~
    if not path.is_file():
        raise SianmsError(
            f"config '{text}' is neither a preset ({', '.join(PRESETS)}) nor an existing JSON file"
        )
    return DetectionConfig.from_dict(read_json(path, RECORD_MAX_BYTES), source=path, name=str(path))


def _failer(source: str | Path):
    def fail(field: str, message: str):
        raise DataFormatError(source, message, field=field)

    return fail
