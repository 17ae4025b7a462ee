"""The detection evaluation of a results file on a split, per region: `sianms metrics`.

The pipeline is the devkit's ``DetectionEval`` (reference §5.3), on arrays:

1. the split's samples in sample-table order; the results must hold every one of them
   (a predefined split: exactly them; a custom split: extra samples are ignored);
2. predictions flattened in the devkit's order: results-file order for a predefined split,
   the split's sample order for a custom split (this decides score ties);
3. ground truth of the detection classes with the devkit's velocity, attribute and points;
4. the range, zero-points (GT only) and bicycle-rack filters;
5. per region (``all``, ``overlap``, ``non-overlap``, one camera pair), the region mask on
   GT and predictions alike, then matching, AP, TP errors, means and NDS.

:func:`evaluate` returns a JSON-ready report whose ``regions`` hold, per region, an object
with the keys of the devkit's ``metrics_summary.json``.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from sianms_cli.errors import DataFormatError, OutputExistsError
from sianms_cli.io import check_writable_output, write_text
from sianms_cli.evaluation.boxes import DETECTION_NAMES, TP_METRICS
from sianms_cli.evaluation.config import DetectionConfig, load_config
from sianms_cli.evaluation.dataset import EvalSplit, bicycle_racks, ego_poses, eval_split, ground_truth
from sianms_cli.evaluation.filters import filter_boxes
from sianms_cli.evaluation.metrics import evaluate_boxes, threshold_key
from sianms_cli.evaluation.regions import (
    ALL,
    centers_in_ego,
    needs_overlap,
    overlap_bits,
    region_mask,
    resolve_regions,
)
from sianms_cli.evaluation.results import (
    Results,
    ResultsFormatError,
    check_box_counts,
    read_results,
    validate_results,
)
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.rigs import sample_rigs


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
) -> dict[str, Any]:
    """Evaluate results on a split, per region.

    Args:
        db: the dataset.
        split: a split name (predefined or from ``<version>/splits.json``) or an EvalSplit.
        results: the results (:func:`~sianms_cli.evaluation.results.read_results`), validated
            here against the configuration's box limit.
        config: a preset name (``detection_cvpr_2019``, ``paper``), a JSON file or a config.
        regions: region names (:mod:`sianms_cli.evaluation.regions`), or one comma-separated string.

    Returns:
        The report: ``split``, ``samples``, ``config`` (its name), ``cfg``, ``boxes`` (counts
        through the filters), ``regions`` {name: metrics_summary-like object, NaN for the
        devkit's exempt TP errors}, ``region_boxes`` {name: {"gt"|"pred": {class: count}}}.
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

    overlap = {"gt": None, "pred": None}
    pair_names: tuple[str, ...] = ()
    if needs_overlap(regions):
        rigs, rig_of_sample = sample_rigs(db, split.sample_tokens)
        for side, boxes in (("gt", gt), ("pred", pred)):
            overlap[side] = overlap_bits(boxes, centers_in_ego(boxes, ego_rotation, ego_translation),
                                         rigs, rig_of_sample)
            pair_names = overlap[side].pair_names
    names = resolve_regions(regions, pair_names)

    summaries: dict[str, dict] = {}
    region_boxes: dict[str, dict] = {}
    for name in names:
        gt_in = gt if name == ALL else gt[region_mask(name, overlap["gt"], len(gt))]
        pred_in = pred if name == ALL else pred[region_mask(name, overlap["pred"], len(pred))]
        summary, _ = evaluate_boxes(gt_in, pred_in, config)
        summary["meta"] = results.meta
        summaries[name] = summary
        region_boxes[name] = {"gt": _class_counts(gt_in, config), "pred": _class_counts(pred_in, config)}
    return {
        "dataroot": str(db.dataroot),
        "version": db.version,
        "split": split.name,
        "samples": len(split),
        "results": results.path,
        "config": config.name,
        "cfg": config.serialize(),
        "boxes": {
            "gt": {"loaded": len(gt_filter.kept), **gt_filter.counts()},
            "pred": {"loaded": len(pred_filter.kept), **pred_filter.counts(), "ignored_samples": ignored},
        },
        "regions": summaries,
        "region_boxes": region_boxes,
        "seconds": time.perf_counter() - started,
    }


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


# --------------------------------------------------------------------------- command


def run_metrics(
    dataroot: str | Path,
    version: str,
    split: str,
    results_path: str | Path,
    config: str | Path | DetectionConfig = "detection_cvpr_2019",
    regions: Sequence[str] = (ALL,),
    out: str | Path | None = None,
    overwrite: bool = False,
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """`sianms metrics`: load the dataset, read the results, evaluate, write ``out``.

    ``out`` is refused before any work when it exists and ``overwrite`` is false, and is
    written atomically (temporary file in the same folder, then a rename). ``progress`` is
    called with the characters of the results file read so far (for a progress bar).
    """
    if out is not None and Path(out).exists() and not overwrite:
        raise OutputExistsError(f"{out} exists; pass --overwrite to replace it")
    config = load_config(config)
    db = NuScenesDB(dataroot, version)
    the_split = eval_split(db, split)
    results = read_results(results_path, max_boxes_per_sample=config.max_boxes_per_sample, progress=progress)
    report = evaluate(db, the_split, results, config, regions)
    if out is not None:
        write_report(out, report, overwrite=overwrite)
    return report


def report_json(report: dict[str, Any]) -> str:
    """The report as strict JSON (NaN and infinities written as null)."""
    return json.dumps(_finite_or_none(report), indent=2, allow_nan=False)


def write_report(path: str | Path, report: dict[str, Any], *, overwrite: bool = False) -> Path:
    """Write the report as strict JSON, atomically; refuses to replace a file unless ``overwrite``."""
    write_text(check_writable_output(path, overwrite=overwrite), report_json(report) + "\n")
    return Path(path)


def _finite_or_none(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: _finite_or_none(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_none(item) for item in value]
    return value


# --------------------------------------------------------------------------- table


_TP_HEADERS = {"trans_err": "ATE", "scale_err": "ASE", "orient_err": "AOE", "vel_err": "AVE", "attr_err": "AAE"}


def format_report(report: dict[str, Any]) -> str:
    """A compact text table per region: per-class AP at each threshold, AP, the five TP errors;
    then the means, mAP and NDS."""
    cfg = report["cfg"]
    thresholds = [threshold_key(th) for th in cfg["dist_ths"]]
    metrics = TP_METRICS
    header = (f"{'class':<22}" + "".join(f"{'AP@' + t:>9}" for t in thresholds) + f"{'AP':>9}"
              + "".join(f"{_TP_HEADERS[m]:>8}" for m in metrics))
    lines = [f"{report['split']}: {report['samples']} samples, config {report['config']}, "
             f"results {report['results']}"]
    for name, summary in report["regions"].items():
        counts = report["region_boxes"][name]
        lines += ["", f"region {name}: {sum(counts['gt'].values())} GT boxes, "
                  f"{sum(counts['pred'].values())} predictions (after filters)", header]
        for cls in cfg["class_range"]:
            lines.append(f"{cls:<22}" + "".join(_cell(summary["label_aps"][cls][t], 9) for t in thresholds)
                         + _cell(summary["mean_dist_aps"][cls], 9)
                         + "".join(_cell(summary["label_tp_errors"][cls][m], 8) for m in metrics))
        lines.append(f"{'mean':<22}" + " " * (9 * len(thresholds)) + _cell(summary["mean_ap"], 9)
                     + "".join(_cell(summary["tp_errors"][m], 8) for m in metrics))
        lines.append(f"mAP {summary['mean_ap']:.4f}   NDS {summary['nd_score']:.4f}")
    return "\n".join(lines)


def _cell(value: float | None, width: int) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return f"{'-':>{width}}"
    return f"{value:>{width}.3f}"
