"""The detection evaluation of a results file on a split, per region: `sianms metrics`.

The pipeline is the devkit's ``DetectionEval``, on arrays (docs/metrics.md#what-is-computed):

1. the split's samples in sample-table order; the results must hold every one of them
   (a predefined split: exactly them; a custom split: extra samples are ignored);
2. predictions flattened in the devkit's order: results-file order for a predefined split,
   the split's sample order for a custom split (this decides score ties);
3. ground truth of the detection classes with the devkit's velocity, attribute and points;
4. the range, zero-points (GT only) and bicycle-rack filters;
5. per region (``all``, ``overlap``, ``non-overlap``, one camera pair), the region mask on
   GT and predictions alike, then matching, AP, TP errors, means and NDS.

A class without ground truth in a region scores AP 0 and TP errors 1 and stays in mAP, the
mean TP errors and NDS, as the devkit scores it; :class:`~sianms_cli.metrics.report.
RegionMetrics` says which classes had none. :func:`run` is the command (a
:class:`MetricsConfig`, an optional JSON output); :func:`evaluate` the same on a loaded dataset
and results. Both return a :class:`~sianms_cli.metrics.report.MetricsReport`.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.json_stream import fits_float
from sianms_cli.metrics.algo import NELEM, MetricData
from sianms_cli.metrics.boxes import DETECTION_NAMES
from sianms_cli.metrics.config import PRESETS, DetectionConfig, load_config
from sianms_cli.metrics.dataset import EvalSplit, bicycle_racks, ego_poses, eval_split, ground_truth
from sianms_cli.metrics.filters import FilterResult, filter_boxes
from sianms_cli.metrics.metrics import evaluate_boxes, threshold_key
from sianms_cli.metrics.regions import (
    ALL,
    EVERY_PAIR,
    NON_OVERLAP,
    OVERLAP,
    PAIR_PREFIX,
    centers_in_ego,
    needs_overlap,
    overlap_bits,
    region_mask,
    resolve_regions,
)
from sianms_cli.metrics.report import FilterCounts, MetricsReport, RegionMetrics, report_json
from sianms_cli.metrics.results import (
    Results,
    ResultsFormatError,
    check_box_counts,
    read_results,
    validate_results,
)
from sianms_cli.io import (check_outside_dataroot, check_writable_output, expand_home, read_json, real_path, write_text,
                           write_files_together)
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.overlap import OverlapBits
from sianms_cli.nuscenes.tables import check_version_name
from sianms_cli.nuscenes.sample_rigs import sample_rigs
from sianms_cli.progress import SILENT, Progress

# --------------------------------------------------------------------------- command


@dataclass(frozen=True, kw_only=True)
class MetricsConfig:
    """What `sianms metrics` evaluates: these fields alone decide the numbers of the report.

    Attributes:
        dataroot, version: the nuScenes-format dataset (``--dataroot``, ``--version``).
        split: a predefined split or a name from ``<version>/splits.json`` (``--split``).
        results: the results file in the nuScenes submission format (``--results``).
        detection_config: a preset (``detection_cvpr_2019``, ``paper``) or a JSON file with
            the devkit's config fields (``--config``).
        regions: region names (:mod:`sianms_cli.metrics.regions`), in report order; a
            comma-separated string is split. Camera pairs are checked against the dataset's
            rigs when it is loaded.

    Raises SianmsError naming the flag for a value that cannot be right on any dataset.
    """

    dataroot: str
    version: str = "v1.0-mini"
    split: str
    results: str
    detection_config: str = "detection_cvpr_2019"
    regions: tuple[str, ...] = (ALL,)

    def __post_init__(self) -> None:
        for name, flag in (("dataroot", "--dataroot"), ("version", "--version"), ("split", "--split"),
                           ("results", "--results"), ("detection_config", "--config")):
            value = str(getattr(self, name))
            if not value.strip():
                raise SianmsError(f"{flag}: must not be empty")
            object.__setattr__(self, name, value)
        check_version_name(self.version)
        if self.detection_config not in PRESETS:  # a file: --config=~/c.json keeps its ~ past the shell
            object.__setattr__(self, "detection_config", str(expand_home(Path(self.detection_config))))
        if self.detection_config not in PRESETS and not Path(self.detection_config).is_file():
            raise SianmsError(f"--config: '{self.detection_config}' is neither a preset "
                              f"({', '.join(PRESETS)}) nor an existing JSON file")
        raw = self.regions.split(",") if isinstance(self.regions, str) else self.regions
        regions = tuple(name.strip() for name in raw if name.strip())
        if not regions:
            raise SianmsError(f"--region: no region given; expected {_REGION_SYNTAX}")
        for name in regions:
            if not _is_region_name(name):
                raise SianmsError(f"--region: unknown region '{name}'; expected {_REGION_SYNTAX}")
        object.__setattr__(self, "regions", regions)


_REGION_SYNTAX = f"{ALL}, {OVERLAP}, {NON_OVERLAP}, '{EVERY_PAIR}' or '{PAIR_PREFIX}CAM_A|CAM_B' (comma-separated)"


def _is_region_name(name: str) -> bool:
    """Whether ``name`` is a region on some rig (a pair's cameras are checked on the dataset)."""
    if name in (ALL, OVERLAP, NON_OVERLAP, EVERY_PAIR):
        return True
    cameras = name[len(PAIR_PREFIX):].split("|") if name.startswith(PAIR_PREFIX) else []
    return len(cameras) == 2 and all(cameras) and cameras[0] != cameras[1]


def run(config: MetricsConfig, out: str | Path | None = None, *, details: str | Path | None = None,
        overwrite: bool = False, progress: Progress = SILENT) -> MetricsReport:
    """`sianms metrics`: load the dataset, read the results, evaluate, write ``out`` if given.

    ``out`` (the JSON report, :func:`~sianms_cli.metrics.report.write_report`) and
    ``details`` (the 101-point curves of every region, :func:`write_details`) are refused
    before any work when they are a folder, the results file, the same file, or exist while
    ``overwrite`` is false; they are written atomically together (:func:`~sianms_cli.io.write_files_together`), so a
    run that fails to write one leaves neither. ``progress`` hears of the results file's bytes
    read, then of the regions evaluated.
    """
    outputs = {flag: path for flag, path in (("--out", out), ("--details", details)) if path is not None}
    for flag, path in outputs.items():
        if real_path(path) == real_path(config.results):
            raise SianmsError(f"{flag}: {path} is the results file; write it elsewhere")
        if real_path(path) == real_path(config.detection_config):
            raise SianmsError(f"{flag}: {path} is the --config file; write it elsewhere")
        check_outside_dataroot(path, config.dataroot, flag, "metrics")
        check_writable_output(path, overwrite=overwrite)
    if out is not None and details is not None and real_path(out) == real_path(details):
        raise SianmsError(f"--details: {details} is also --out; give each its own file")
    detection = load_config(config.detection_config)
    db = NuScenesDB(config.dataroot, config.version)
    split = eval_split(db, config.split)
    results_path = Path(config.results)
    if results_path.is_file():
        progress.start(results_path.stat().st_size, "B", "reading results")
    results = read_results(results_path, max_boxes_per_sample=detection.max_boxes_per_sample,
                           progress=progress.advance)
    curves: dict[str, dict[str, MetricData]] = {}

    def keep_curves(region: str, gt: np.ndarray, pred: np.ndarray, region_curves: dict) -> None:
        curves[region] = details_of(region_curves)

    report = evaluate(db, split, results, detection, config.regions, progress=progress,
                      inspect=keep_curves if details is not None else None)
    texts = {Path(out): report_json(report) + "\n"} if out is not None else {}
    if details is not None:
        texts[Path(details)] = details_json(curves)
    write_files_together(texts, overwrite=overwrite)
    return report


# --------------------------------------------------------------------------- curves: metrics_details.json


def detail_key(class_name: str, dist_th: float) -> str:
    """The devkit's key of one curve in ``metrics_details.json``: ``"car:2.0"``."""
    return f"{class_name}:{threshold_key(dist_th)}"


def details_of(curves: Mapping[tuple[str, float], MetricData]) -> dict[str, MetricData]:
    """One region's curves (``evaluate``'s ``inspect`` argument) keyed as the devkit's file keys them."""
    return {detail_key(name, dist_th): data for (name, dist_th), data in curves.items()}


def write_details(path: str | Path, details: Mapping[str, Mapping[str, MetricData]], *,
                  overwrite: bool = False) -> Path:
    """Write ``{region: {"<class>:<dist_th>": MetricData}}`` atomically as strict JSON.

    Each region's object is the devkit's ``metrics_details.json`` (``MetricData.serialize()``
    per key); a NaN (a TP error the devkit does not measure for the class) is written as
    ``null``. Refuses a folder, and an existing file unless ``overwrite``.
    """
    return write_text(check_writable_output(path, overwrite=overwrite), details_json(details))


def details_json(details: Mapping[str, Mapping[str, MetricData]]) -> str:
    """The text :func:`write_details` writes."""
    content = {region: {key: {name: [value if math.isfinite(value) else None for value in values]
                              for name, values in data.serialize().items()}
                        for key, data in by_key.items()}
               for region, by_key in details.items()}
    return json.dumps(content, allow_nan=False) + "\n"


def read_details(path: str | Path) -> dict[str, dict[str, MetricData]]:
    """Read a file written by :func:`write_details`; DataFormatError names the file and field."""
    content = read_json(path)
    if not isinstance(content, dict):
        raise DataFormatError(path, f"must be an object of regions, got {type(content).__name__}")
    return {region: {key: _metric_data(path, f"{region}.{key}", data)
                     for key, data in _object(path, region, by_key).items()}
            for region, by_key in content.items()}


def _object(path: str | Path, field: str, value: Any) -> dict:
    if not isinstance(value, dict):
        raise DataFormatError(path, f"must be an object, got {type(value).__name__}", field=field)
    return value


def _metric_data(path: str | Path, field: str, value: Any) -> MetricData:
    """One ``MetricData.serialize()`` entry: every curve, 101 numbers (``null`` read as NaN)."""
    curves = _object(path, field, value)
    for name in MetricData.__dataclass_fields__:
        values = curves.get(name)
        if (not isinstance(values, list) or len(values) != NELEM or not all(
                item is None or (isinstance(item, (int, float)) and not isinstance(item, bool)) for item in values)
                or not fits_float([item for item in values if item is not None])):
            raise DataFormatError(path, f"must be a list of {NELEM} numbers or nulls", field=f"{field}.{name}")
    return MetricData.deserialize(curves)


# --------------------------------------------------------------------------- evaluation


def align_results(results: Results, split: EvalSplit) -> tuple[np.ndarray, int]:
    """The predictions of the split's samples in the devkit's flattened order.

    Returns:
        ``(boxes, ignored)``: a box table whose ``sample`` indexes ``split.sample_tokens``, and
        the number of results samples outside a custom split (ignored, as by the devkit).

    Raises:
        ResultsFormatError: a sample of the split is missing, or (predefined split) the
        results hold a sample that is not in the split.
    """
    position = {token: i for i, token in enumerate(split.sample_tokens)}
    index = np.array([position.get(token, -1) for token in results.sample_tokens], dtype=np.int64)
    present = set(results.sample_tokens)
    missing = [token for token in split.sample_tokens if token not in present]
    if missing:
        raise ResultsFormatError(
            results.path, f"sample of split '{split.name}' missing ({len(missing)} of {len(split)} missing); "
            "every sample of the split must be listed, with [] when it has no box",
            token=missing[0], field="results")
    extra = np.flatnonzero(index < 0)
    if split.predefined and len(extra):
        raise ResultsFormatError(
            results.path, f"not a sample of split '{split.name}' ({len(extra)} such samples); the results "
            "of a predefined split must hold exactly its samples", token=results.sample_tokens[extra[0]],
            field="results")
    split_index = index[results.boxes["sample"]]
    rows = np.flatnonzero(split_index >= 0)
    if not split.predefined:
        rows = rows[np.argsort(split_index[rows], kind="stable")]
    kept = results.boxes[rows]  # the one copy of the predictions
    kept["sample"] = split_index[rows]
    return kept, len(extra)


def evaluate(
    db: NuScenesDB,
    split: str | EvalSplit,
    results: Results,
    config: str | Path | DetectionConfig = "detection_cvpr_2019",
    regions: Sequence[str] | str = (ALL,),
    *,
    progress: Progress = SILENT,
    inspect: Callable[[str, np.ndarray, np.ndarray, dict], None] | None = None,
) -> MetricsReport:
    """Evaluate results on a split, per region.

    Args:
        db: the dataset.
        split: a split name (predefined or from ``<version>/splits.json``) or an EvalSplit.
        results: the results (:func:`~sianms_cli.metrics.results.read_results`), validated
            here against the configuration's box limit.
        config: a preset name (``detection_cvpr_2019``, ``paper``), a JSON file or a config.
        regions: region names (:mod:`sianms_cli.metrics.regions`), or one comma-separated string.
        progress: told of each region evaluated.
        inspect: called per region with (name, its filtered GT and predictions as box tables,
            the 101-point curves by (class, threshold)), for figures the report does not keep
            (precision-recall curves, duplicates).

    Returns:
        The report; its regions are in the order asked for, ``overlap:*`` expanded.
    """
    started = time.perf_counter()
    regions = regions.split(",") if isinstance(regions, str) else list(regions)
    config = load_config(config)
    split = eval_split(db, split) if isinstance(split, str) else split
    if results.validated:
        check_box_counts(results, config.max_boxes_per_sample)
    else:
        validate_results(results, config.max_boxes_per_sample)
    pred, ignored = align_results(results, split)
    gt, annotation_rows = ground_truth(db, split)
    ego_rotation, ego_translation = ego_poses(db, split)
    racks = bicycle_racks(db, split)
    gt_filter = filter_boxes(gt, ego_translation, racks, config, ground_truth=True)
    pred_filter = filter_boxes(pred, ego_translation, racks, config, ground_truth=False)
    gt, pred = gt[gt_filter.kept], pred[pred_filter.kept]
    _check_gt_sizes(db, gt, annotation_rows[gt_filter.kept])

    overlap: dict[str, OverlapBits | None] = {"gt": None, "pred": None}
    pair_names: tuple[str, ...] = ()
    if needs_overlap(regions):
        rigs, rig_of_sample = sample_rigs(db, split.sample_tokens)
        for side, boxes in (("gt", gt), ("pred", pred)):
            bits = overlap_bits(boxes, centers_in_ego(boxes, ego_rotation, ego_translation), rigs, rig_of_sample)
            overlap[side] = bits
            pair_names = bits.pair_names
    names = resolve_regions(regions, pair_names)

    progress.start(len(names), "region", "evaluating")
    metrics: dict[str, RegionMetrics] = {}
    for name in names:
        gt_in = gt if name == ALL else gt[region_mask(name, overlap["gt"], len(gt))]
        pred_in = pred if name == ALL else pred[region_mask(name, overlap["pred"], len(pred))]
        summary, curves = evaluate_boxes(gt_in, pred_in, config)
        if inspect is not None:
            inspect(name, gt_in, pred_in, curves)
        metrics[name] = RegionMetrics(
            label_aps=summary["label_aps"], mean_dist_aps=summary["mean_dist_aps"], mean_ap=summary["mean_ap"],
            label_tp_errors=summary["label_tp_errors"], tp_errors=summary["tp_errors"],
            tp_scores=summary["tp_scores"], nd_score=summary["nd_score"], eval_time=summary["eval_time"],
            gt_counts=_class_counts(gt_in, config), pred_counts=_class_counts(pred_in, config))
        progress.advance()
    return MetricsReport(
        dataroot=str(db.dataroot), version=db.version, split=split.name, samples=len(split), results=results.path,
        cfg=config, meta=results.meta, gt_filter=_filter_counts(gt_filter), pred_filter=_filter_counts(pred_filter),
        ignored_samples=ignored, regions=metrics, seconds=time.perf_counter() - started)


def _filter_counts(result: FilterResult) -> FilterCounts:
    return FilterCounts(loaded=len(result.kept), **result.counts())


def _class_counts(boxes: np.ndarray, config: DetectionConfig) -> dict[str, int]:
    counts = np.bincount(boxes["label"], minlength=len(DETECTION_NAMES))
    return {name: int(counts[label]) for name, label in zip(config.class_names, config.labels)}


def _check_gt_sizes(db: NuScenesDB, gt: np.ndarray, annotation_rows: np.ndarray) -> None:
    """A ground-truth box the evaluation may match needs a positive size (the devkit asserts)."""
    bad = ~(gt["size"] > 0).all(axis=1)
    if bad.any():
        annotations = db.table("sample_annotation")
        row = int(annotation_rows[np.flatnonzero(bad)[0]])
        raise DataFormatError(annotations.path, f"size must be positive to be evaluated, got "
                              f"{annotations.column('size')[row].tolist()}", token=str(annotations.tokens[row]),
                              field="size")
