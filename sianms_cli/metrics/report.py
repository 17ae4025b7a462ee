"""The result of `sianms metrics` as a typed report that writes to JSON and reads back equal.

:class:`MetricsReport` holds what was evaluated, how many boxes each filter removed, and one
:class:`RegionMetrics` per region; `sianms metrics --out` writes it and later commands
(``sianms report``) read it back, so the JSON is versioned (docs/metrics.md#the-json-report):

.. code-block:: text

    {"schema": "sianms-metrics", "schema_version": 1,
     "dataroot": str, "version": str, "split": str, "samples": int, "results": str,
     "config": <config name>, "cfg": <the devkit's DetectionConfig.serialize()>,
     "meta": <the results file's meta>,
     "boxes": {"gt": {"loaded", "kept", "out_of_range", "without_points", "in_bicycle_rack"},
               "pred": {... the same ..., "ignored_samples"}},
     "regions": {name: <the devkit's metrics_summary.json: label_aps, mean_dist_aps, mean_ap,
                        label_tp_errors, tp_errors, tp_scores, nd_score, eval_time, cfg, meta>},
     "region_boxes": {name: {"gt": {class: count}, "pred": {class: count}}},
     "seconds": float}

The JSON is strict: the devkit's NaN TP errors are written as ``null`` and read back as NaN.
Classes, thresholds and regions keep their order; equal reports serialise to identical text.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, Mapping, NoReturn, Sequence

import numpy as np

from sianms_cli.errors import DataFormatError
from sianms_cli.metrics.boxes import TP_METRICS
from sianms_cli.metrics.config import DetectionConfig
from sianms_cli.metrics.metrics import threshold_key
from sianms_cli.io import check_writable_output, read_json, write_text

SCHEMA = "sianms-metrics"
SCHEMA_VERSION = 1

_TOP_KEYS = ("schema", "schema_version", "dataroot", "version", "split", "samples", "results", "config", "cfg",
             "meta", "boxes", "regions", "region_boxes", "seconds")
_SUMMARY_KEYS = ("label_aps", "mean_dist_aps", "mean_ap", "label_tp_errors", "tp_errors", "tp_scores", "nd_score",
                 "eval_time")


@dataclass(frozen=True)
class FilterCounts:
    """How many boxes were loaded, kept, and removed by each of the devkit's filters, in order."""

    loaded: int
    kept: int
    out_of_range: int
    without_points: int
    in_bicycle_rack: int


@dataclass(frozen=True, eq=False)
class RegionMetrics:
    """The metrics of one region: the devkit's ``DetectionMetrics`` summary and the box counts.

    The first eight fields are the devkit's ``metrics_summary.json`` values, classes in
    configuration order, thresholds keyed as ``"0.5"``, ``"1.0"`` ...; a TP error the devkit
    does not measure for a class is NaN. ``gt_counts`` and ``pred_counts`` are the boxes of each
    class in the region after the filters: ``gt_counts`` is the devkit's ``npos``.
    """

    label_aps: Mapping[str, Mapping[str, float]]
    mean_dist_aps: Mapping[str, float]
    mean_ap: float
    label_tp_errors: Mapping[str, Mapping[str, float]]
    tp_errors: Mapping[str, float]
    tp_scores: Mapping[str, float]
    nd_score: float
    eval_time: float
    gt_counts: Mapping[str, int]
    pred_counts: Mapping[str, int]

    @property
    def classes(self) -> tuple[str, ...]:
        """The evaluated classes, in configuration order: mAP and the mean errors are over these."""
        return tuple(self.mean_dist_aps)

    @property
    def classes_without_gt(self) -> tuple[str, ...]:
        """Classes with no ground-truth box in the region.

        The devkit (``accumulate``: ``npos == 0`` returns ``DetectionMetricData.no_predictions()``)
        gives them AP 0 and TP errors 1 whatever was predicted, and keeps them in mAP, the mean
        TP errors and NDS. Over the whole split this is rare; in a camera-pair region it is the
        rule, and a perfect detector then scores mAP = (classes with GT) / (classes).
        """
        return tuple(name for name in self.classes if self.gt_counts[name] == 0)

    @property
    def mean_ap_of_classes_with_gt(self) -> float:
        """Mean AP over the classes that have ground truth in the region; NaN if none has.

        Not a devkit number: shown beside the devkit's mAP so that a sub-region's score can be
        read without the classes that happen to be absent from it.
        """
        aps = [self.mean_dist_aps[name] for name in self.classes if self.gt_counts[name] > 0]
        return float(np.mean(aps)) if aps else math.nan

    def summary(self) -> dict[str, Any]:
        """The devkit's ``metrics_summary.json`` values (without cfg and meta), NaN kept."""
        return {key: getattr(self, key) for key in _SUMMARY_KEYS}

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, RegionMetrics):
            return NotImplemented
        return (_finite_or_none(self.summary()) == _finite_or_none(other.summary())
                and dict(self.gt_counts) == dict(other.gt_counts) and dict(self.pred_counts) == dict(other.pred_counts))

    # Unhashable, as equal values that may change must be; typeshed types object.__hash__ as a method only.
    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, eq=False)
class MetricsReport:
    """Everything `sianms metrics` computed, and what it was computed on.

    Attributes:
        dataroot, version, split: the dataset and split evaluated.
        samples: the number of samples of the split.
        results: the results file (``"<results>"`` for results built in memory).
        cfg: the resolved detection configuration (``cfg.name``: preset name or file).
        meta: the results file's ``meta`` object.
        gt_filter, pred_filter: box counts through the filters, over the whole split.
        ignored_samples: results samples outside a custom split (ignored, as by the devkit).
        regions: {region name: metrics}, in the order asked for.
        seconds: wall time of the evaluation (loading the split to the last region).
    """

    dataroot: str
    version: str
    split: str
    samples: int
    results: str
    cfg: DetectionConfig
    meta: Mapping[str, Any]
    gt_filter: FilterCounts
    pred_filter: FilterCounts
    ignored_samples: int
    regions: Mapping[str, RegionMetrics]
    seconds: float

    def serialize(self) -> dict[str, Any]:
        """The JSON-ready report (module docstring): strict JSON, NaN written as None; no two
        parts share a mutable object."""
        return {
            "schema": SCHEMA,
            "schema_version": SCHEMA_VERSION,
            "dataroot": self.dataroot,
            "version": self.version,
            "split": self.split,
            "samples": self.samples,
            "results": self.results,
            "config": self.cfg.name,
            "cfg": self.cfg.serialize(),
            "meta": dict(self.meta),
            "boxes": {"gt": asdict(self.gt_filter),
                      "pred": {**asdict(self.pred_filter), "ignored_samples": self.ignored_samples}},
            "regions": {name: {**_finite_or_none(region.summary()), "cfg": self.cfg.serialize(),
                               "meta": dict(self.meta)} for name, region in self.regions.items()},
            "region_boxes": {name: {"gt": dict(region.gt_counts), "pred": dict(region.pred_counts)}
                             for name, region in self.regions.items()},
            "seconds": self.seconds,
        }

    @classmethod
    def deserialize(cls, content: Any, *, source: str | Path = "<report>") -> MetricsReport:
        """The report from its JSON form, checked field by field.

        Raises:
            DataFormatError: naming ``source`` and the field (``regions.overlap.label_aps.car``)
            of the first value that is missing, of the wrong type, or inconsistent with ``cfg``.
        """
        read = _Reader(source)
        top = read.exact_keys(content, "", _TOP_KEYS)
        if top["schema"] != SCHEMA:
            read.fail("schema", f"not a sianms metrics report: expected '{SCHEMA}', got {top['schema']!r}")
        if top["schema_version"] != SCHEMA_VERSION:
            read.fail("schema_version", f"this sianms reads version {SCHEMA_VERSION}, got {top['schema_version']!r}")
        cfg = read.config(top["cfg"], read.string(top["config"], "config"))
        meta = read.object(top["meta"], "meta")
        boxes = read.exact_keys(top["boxes"], "boxes", ("gt", "pred"))
        pred_counts = read.exact_keys(boxes["pred"], "boxes.pred", _FILTER_KEYS + ("ignored_samples",))
        regions = read.object(top["regions"], "regions")
        region_boxes = read.exact_keys(top["region_boxes"], "region_boxes", tuple(regions))
        return cls(
            dataroot=read.string(top["dataroot"], "dataroot"),
            version=read.string(top["version"], "version"),
            split=read.string(top["split"], "split"),
            samples=read.count(top["samples"], "samples"),
            results=read.string(top["results"], "results"),
            cfg=cfg,
            meta=meta,
            gt_filter=read.filter_counts(boxes["gt"], "boxes.gt"),
            pred_filter=read.filter_counts({key: pred_counts[key] for key in _FILTER_KEYS}, "boxes.pred"),
            ignored_samples=read.count(pred_counts["ignored_samples"], "boxes.pred.ignored_samples"),
            regions={name: read.region(value, region_boxes[name], name, cfg, top["cfg"], meta)
                     for name, value in regions.items()},
            seconds=read.number(top["seconds"], "seconds"),
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, MetricsReport):
            return NotImplemented
        return self.serialize() == other.serialize()

    # Unhashable, as equal values that may change must be; typeshed types object.__hash__ as a method only.
    __hash__ = None  # type: ignore[assignment]


def report_json(report: MetricsReport) -> str:
    """The report as indented strict JSON text (no NaN, no infinity), keys in report order."""
    return json.dumps(report.serialize(), indent=2, allow_nan=False)


def write_report(path: str | Path, report: MetricsReport, *, overwrite: bool = False) -> Path:
    """Write the report atomically; refuses a folder, and an existing file unless ``overwrite``."""
    return write_text(check_writable_output(path, overwrite=overwrite), report_json(report) + "\n")


def read_report(path: str | Path) -> MetricsReport:
    """Read a report written by :func:`write_report`; DataFormatError names the file and field."""
    return MetricsReport.deserialize(read_json(path), source=path)


def _finite_or_none(value: Any) -> Any:
    """``value`` with every NaN or infinite float, however nested in dicts, replaced by None."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {key: _finite_or_none(item) for key, item in value.items()}
    return value


_FILTER_KEYS = tuple(field.name for field in fields(FilterCounts))


class _Reader:
    """Checks of decoded JSON values that fail with one DataFormatError naming the source and field."""

    def __init__(self, source: str | Path) -> None:
        self.source = source

    def fail(self, field: str, message: str) -> NoReturn:
        raise DataFormatError(self.source, message, field=field or None)

    def object(self, value: Any, field: str) -> dict:
        if not isinstance(value, dict):
            self.fail(field, f"must be an object, got {type(value).__name__}")
        return value

    def exact_keys(self, value: Any, field: str, keys: Sequence[str]) -> dict:
        """An object with exactly ``keys`` (in any order), returned in the order of ``keys``."""
        value = self.object(value, field)
        prefix = f"{field}." if field else ""
        missing = [key for key in keys if key not in value]
        if missing:
            self.fail(prefix + missing[0], "missing")
        unknown = [key for key in value if key not in keys]
        if unknown:
            self.fail(prefix + unknown[0], f"unexpected; expected only {', '.join(keys)}")
        return {key: value[key] for key in keys}

    def string(self, value: Any, field: str) -> str:
        if not isinstance(value, str):
            self.fail(field, f"must be a string, got {value!r}")
        return value

    def count(self, value: Any, field: str) -> int:
        if not isinstance(value, int) or isinstance(value, bool) or value < 0:
            self.fail(field, f"must be a non-negative integer, got {value!r}")
        return value

    def number(self, value: Any, field: str, *, nullable: bool = False) -> float:
        """A float; ``null`` (a NaN written as strict JSON) is NaN where ``nullable``."""
        if value is None and nullable:
            return math.nan
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            self.fail(field, f"must be a number{' or null' if nullable else ''}, got {value!r}")
        return float(value)

    def numbers(self, value: Any, field: str, keys: Sequence[str], *, nullable: bool = False) -> dict[str, float]:
        value = self.exact_keys(value, field, keys)
        return {key: self.number(item, f"{field}.{key}", nullable=nullable) for key, item in value.items()}

    def config(self, value: Any, name: str) -> DetectionConfig:
        try:
            return DetectionConfig.from_dict(self.object(value, "cfg"), source=self.source, name=name)
        except DataFormatError as error:
            if error.path != str(self.source) or error.field is None:
                raise
            self.fail(f"cfg.{error.field}", error.detail)

    def filter_counts(self, value: Any, field: str) -> FilterCounts:
        value = self.exact_keys(value, field, _FILTER_KEYS)
        return FilterCounts(**{key: self.count(item, f"{field}.{key}") for key, item in value.items()})

    def region(self, value: Any, boxes: Any, name: str, cfg: DetectionConfig, cfg_json: Any,
               meta: dict) -> RegionMetrics:
        """One region from its ``regions`` and ``region_boxes`` entries, checked against ``cfg``."""
        field = f"regions.{name}"
        value = self.exact_keys(value, field, _SUMMARY_KEYS + ("cfg", "meta"))
        if value["cfg"] != cfg_json:
            self.fail(f"{field}.cfg", "differs from the report's cfg")
        if value["meta"] != meta:
            self.fail(f"{field}.meta", "differs from the report's meta")
        classes = cfg.class_names
        thresholds = tuple(threshold_key(th) for th in cfg.dist_ths)
        boxes = self.exact_keys(boxes, f"region_boxes.{name}", ("gt", "pred"))
        counts = {side: self.exact_keys(boxes[side], f"region_boxes.{name}.{side}", classes) for side in boxes}
        return RegionMetrics(
            label_aps={cls: self.numbers(aps, f"{field}.label_aps.{cls}", thresholds)
                       for cls, aps in self.exact_keys(value["label_aps"], f"{field}.label_aps", classes).items()},
            mean_dist_aps=self.numbers(value["mean_dist_aps"], f"{field}.mean_dist_aps", classes),
            mean_ap=self.number(value["mean_ap"], f"{field}.mean_ap"),
            label_tp_errors={
                cls: self.numbers(errors, f"{field}.label_tp_errors.{cls}", TP_METRICS, nullable=True)
                for cls, errors in self.exact_keys(value["label_tp_errors"], f"{field}.label_tp_errors",
                                                   classes).items()},
            tp_errors=self.numbers(value["tp_errors"], f"{field}.tp_errors", TP_METRICS, nullable=True),
            tp_scores=self.numbers(value["tp_scores"], f"{field}.tp_scores", TP_METRICS),
            nd_score=self.number(value["nd_score"], f"{field}.nd_score"),
            eval_time=self.number(value["eval_time"], f"{field}.eval_time"),
            gt_counts={cls: self.count(n, f"region_boxes.{name}.gt.{cls}") for cls, n in counts["gt"].items()},
            pred_counts={cls: self.count(n, f"region_boxes.{name}.pred.{cls}") for cls, n in counts["pred"].items()},
        )
