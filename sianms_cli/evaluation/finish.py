"""The finish stage of `sianms eval`: results files, metrics per method and region, re-identification quality,
and the thresholds.

Runs once every scene's boxes table exists (:mod:`.job`). Ground truth enters here only, to
score: the metrics (``sianms metrics``' evaluator, the ``paper`` config) and the
re-identification figures (the ``correct`` flag of each match, and the oracle's matches as
the pairs there were to find); and to choose the thresholds this split would choose
(``thresholds.json``, :mod:`.calibration`), which only a later evaluation of other scenes
(``--thresholds-from``) uses. With a calibration, each NMS family's ``best_nms`` in the table is
the calibration's choice, not this split's.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from sianms_cli.data.cache import complete_manifest, reading_shard
from sianms_cli.errors import DataFormatError
from sianms_cli.metrics.boxes import ATTRIBUTE, BOX_DTYPE, LABEL, NO_ATTRIBUTE
from sianms_cli.metrics.config import load_config
from sianms_cli.metrics.dataset import eval_split
from sianms_cli.metrics.algo import MetricData
from sianms_cli.metrics.evaluate import detail_key, evaluate, write_details
from sianms_cli.metrics.report import MetricsReport, write_report
from sianms_cli.metrics.results import results_from_boxes, write_results
from sianms_cli.geometry.quaternion import yaw_to_quat
from sianms_cli.io import write_json, write_text
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.evaluation.calibration import (THRESHOLDS_FILE, Calibration, calibrated_best, choose_dis_thr,
                                             thresholds_record, thresholds_used)
from sianms_cli.evaluation.matching import pair_quality
from sianms_cli.evaluation.methods import (GATED_SIANMS, HYBRID, MATCHERS, ORACLE, SIANMS, AllBoxes, kept_matches,
                                         match_kind, select, split_name)
from sianms_cli.evaluation.scene import BOXES_SCHEMA, VECTOR_WIDTHS
from sianms_cli.evaluation.scoring import RegionFigures
from sianms_cli.progress import Progress

REGIONS = ("all", "overlap", "overlap:*")
CURVE_REGIONS = ("all", "overlap")  # metrics_details_<method>.json: the regions of Table I
METRICS_CONFIG = "paper"
DEFAULT_ATTRIBUTE = {"car": "vehicle.parked", "truck": "vehicle.parked", "trailer": "vehicle.parked",
                     "construction_vehicle": "vehicle.parked", "bus": "vehicle.stopped",
                     "pedestrian": "pedestrian.standing", "bicycle": "cycle.without_rider",
                     "motorcycle": "cycle.without_rider", "barrier": "", "traffic_cone": ""}
PICTURE_METHODS = ("vanilla", "axis-nms", "sianms", "oracle")  # the paper's Fig. 5 columns, and the ceiling
RESULTS_META = {"use_camera": True, "use_lidar": True, "use_radar": False, "use_map": False, "use_external": False}


SCENE_AGAIN = "delete it and rerun the same `sianms eval`, which evaluates its scene again"
BOX_KINDS = ("single", SIANMS, ORACLE)  # what the scenes stage writes in ``kind``


def _read_scene_table(path: Path) -> pa.Table:
    """One scene's boxes table, refused (naming the file, row and field) where an edit or another
    file broke it: read as it stands, a missing column is all nulls and a bad value is blamed on
    the results file its box goes to."""
    with reading_shard(path, SCENE_AGAIN):
        schema = pq.read_schema(path)
        for field in BOXES_SCHEMA:
            index = schema.get_field_index(field.name)
            if index < 0:
                raise DataFormatError(path, f"no such column; {SCENE_AGAIN}", field=field.name)
            if schema.field(index).type != field.type:
                raise DataFormatError(path, f"{schema.field(index).type} where eval writes {field.type}; "
                                            f"{SCENE_AGAIN}", field=field.name)
        table = pq.read_table(path, schema=BOXES_SCHEMA)
    for name, broken, expected in broken_rows(table):
        rows = np.flatnonzero(broken)
        if len(rows):
            raise DataFormatError(path, f"row {rows[0]}: expected {expected}; {SCENE_AGAIN}", field=name)
    return table


def broken_rows(table: pa.Table) -> list[tuple[str, np.ndarray, str]]:
    """(field, rows (N,) bool where its value breaks what the scenes stage writes, what it writes)."""
    def values(name: str) -> np.ndarray:
        return table[name].to_numpy(zero_copy_only=False)

    def missing(name: str) -> np.ndarray:
        return table[name].is_null().to_numpy(zero_copy_only=False)

    def vector_broken(name: str, positive: bool = False) -> np.ndarray:
        column = table[name].combine_chunks()
        flat = pc.list_flatten(column)
        good = pc.is_finite(flat).to_numpy(zero_copy_only=False)
        if positive:
            good &= flat.to_numpy(zero_copy_only=False) > 0
        bad = np.zeros(len(column), dtype=bool)
        bad[pc.list_parent_indices(column).to_numpy()[~good]] = True
        return bad | missing(name)

    score = values("score").astype(np.float64)
    has_box = ~values("dismissed").astype(bool) & ~missing("dismissed")
    return [
        ("kind", ~np.isin(values("kind"), BOX_KINDS), " or ".join(BOX_KINDS)),
        ("class", ~np.isin(values("class"), list(LABEL)), "a detection class"),
        ("detection_a", missing("detection_a"), "a detection id"),
        ("score", ~(np.isfinite(score) & (score >= 0) & (score <= 1)), "a score in [0, 1]"),
        ("dismissed", missing("dismissed"), "true or false"),
        ("translation", has_box & vector_broken("translation"), "3 finite numbers for a box"),
        ("size", has_box & vector_broken("size", positive=True), "3 positive numbers for a box"),
        ("yaw", has_box & ~np.isfinite(values("yaw").astype(np.float64)), "a finite number for a box"),
    ]


def read_boxes(paths: list[Path], sample_tokens: list[str]) -> AllBoxes:
    """The scenes' boxes tables (:data:`~.scene.BOXES_SCHEMA`) as :class:`AllBoxes`, samples indexed in
    ``sample_tokens``."""
    table = pa.concat_tables([_read_scene_table(path) for path in paths])
    position = pc.index_in(table["sample_token"], value_set=pa.array(sample_tokens, pa.string()))
    if position.null_count:
        unknown = table["sample_token"].filter(position.is_null())[0].as_py()
        raise DataFormatError(paths[0].parent, f"boxes of sample {unknown}, which is not in the split",
                              field="sample_token")

    def vectors(name: str) -> np.ndarray:
        column = table[name].combine_chunks()
        width = VECTOR_WIDTHS[name]
        values = np.full((len(column), width), np.nan)
        valid = column.is_valid().to_numpy(zero_copy_only=False)
        lengths = pc.list_value_length(column).fill_null(width).to_numpy(zero_copy_only=False)
        if (lengths != width).any():
            raise DataFormatError(paths[0].parent, f"a row whose {name} holds {lengths[lengths != width][0]} values, "
                                  f"not {width}", field=name)
        values[valid] = column.drop_null().flatten().to_numpy().reshape(-1, width)
        return values

    def strings(name: str) -> np.ndarray:
        return table[name].fill_null("").to_numpy(zero_copy_only=False).astype(str)

    return AllBoxes(
        sample=position.to_numpy(zero_copy_only=False).astype(np.int64),
        kind=strings("kind"), detection_a=strings("detection_a"), detection_b=strings("detection_b"),
        classes=strings("class"), score=table["score"].to_numpy().astype(np.float64),
        translation=vectors("translation"), size=vectors("size"),
        yaw=table["yaw"].to_numpy(zero_copy_only=False).astype(np.float64),
        dismissed=table["dismissed"].to_numpy(zero_copy_only=False).astype(bool),
        correct=table["correct"].fill_null(False).to_numpy(zero_copy_only=False).astype(bool),
        wedges=vectors("wedges"))


def box_table(boxes: AllBoxes, rows: np.ndarray, default_attribute: dict[str, str]) -> np.ndarray:
    """The selected rows as a results box table (:data:`~sianms_cli.metrics.boxes.BOX_DTYPE`)."""
    table = np.zeros(len(rows), dtype=BOX_DTYPE)
    table["sample"] = boxes.sample[rows]
    names, index = np.unique(boxes.classes[rows], return_inverse=True)  # a lookup per class, not per box
    table["label"] = np.array([LABEL[name] for name in names], dtype=np.int8)[index]
    table["attribute"] = np.array([ATTRIBUTE[default_attribute[name]] if default_attribute.get(name)
                                   else NO_ATTRIBUTE for name in names], dtype=np.int8)[index]
    table["translation"] = boxes.translation[rows]
    table["size"] = boxes.size[rows]
    table["rotation"] = yaw_to_quat(boxes.yaw[rows])
    table["velocity"] = 0.0
    table["score"] = boxes.score[rows]
    table["num_pts"] = -1
    return table


def reidentification(boxes: AllBoxes, gated: bool = False) -> dict[str, dict[str, float | None]]:
    """Pair precision / recall / F1 of each matcher's kept matches against ground-truth identity.

    The pairs to find are the oracle's (same instance, both candidates under the same rule),
    before the frustum-overlap dismissal; the dismissals are counted separately, with how many
    of them were right. A wrong kept match is counted by what went wrong:
    ``wrong_without_partner`` when neither detection is in a true pair (no right match existed
    for them: only ``dis_thr`` could have refused it), ``wrong_partner_passed_over`` when one
    of them is (the embedding or the assignment passed its true partner over). With ``gated``,
    ``gated-sianms`` is scored too, with the siaNMS matches its gate refused (``gate_refused``)
    and how many of them were right.
    """
    oracle = boxes.kind == ORACLE
    partnered = np.union1d(boxes.detection_a[oracle], boxes.detection_b[oracle])
    has_partner = np.isin(boxes.detection_a, partnered) | np.isin(boxes.detection_b, partnered)
    out = {}
    for matcher in (SIANMS, GATED_SIANMS, ORACLE) if gated else (SIANMS, ORACLE):
        mine = boxes.kind == match_kind(matcher)
        kept = kept_matches(boxes, matcher)
        wrong = kept & ~boxes.correct
        figures = pair_quality(int(kept.sum()), int((kept & boxes.correct).sum()), int(oracle.sum()))
        figures["wrong_without_partner"] = int((wrong & ~has_partner).sum())
        figures["wrong_partner_passed_over"] = int((wrong & has_partner).sum())
        figures["dismissed"] = int((mine & boxes.dismissed).sum())
        figures["dismissed_right"] = int((mine & boxes.dismissed & boxes.correct).sum())
        if matcher == GATED_SIANMS:
            refused = mine & ~boxes.dismissed & ~kept
            figures["gate_refused"] = int(refused.sum())
            figures["gate_refused_right"] = int((refused & boxes.correct).sum())
        out[matcher] = figures
    return out


def finish(db: NuScenesDB, config, out: Path, scene_paths: list[Path], timings: dict[str, float],
           progress: Progress, *, resolved: dict[str, Any], models: Any, calibration: Calibration | None = None
           ) -> tuple[dict[str, Any], list[str]]:
    """Write every method's results, metrics and curves, the table, the re-identification figures and the
    thresholds this split chooses; return the table and the names of the pictures drawn.

    Args:
        resolved: the evaluation's eval.json config (its ``dis_thr`` is the one the scenes used).
        models: the loaded runs (:class:`~.job.Models`): the siamese encoder chooses this split's ``dis_thr``.
        calibration: the ``--thresholds-from`` evaluation, whose NMS choices the table reports as each
            family's best; None: this split's own.
    """
    from sianms_cli.reporting.eval_pictures import draw_pr_curves
    from sianms_cli.reporting.eval_table import TABLE_CLASS, eval_table, table_markdown

    split = eval_split(db, config.split)
    boxes = read_boxes(scene_paths, list(split.sample_tokens))
    metrics_config = load_config(METRICS_CONFIG)
    reports: dict[str, MetricsReport] = {}
    counts: dict[str, int] = {}
    duplicates: dict[str, dict[str, dict[str, int]]] = {}
    curves_at_tp: dict[str, dict[str, MetricData]] = {}
    methods = config.method_names
    progress.start(len(methods), "method", "scoring")
    for method in methods:
        started = time.perf_counter()
        rows = select(boxes, method, config.axis_mode)
        timings[f"select_{method}_s"] = time.perf_counter() - started
        counts[method] = len(rows)
        results = results_from_boxes(split.sample_tokens, box_table(boxes, rows, DEFAULT_ATTRIBUTE), RESULTS_META,
                                     path=str(out / f"results_{method}.json"))
        write_results(out / f"results_{method}.json", results, overwrite=True)
        started = time.perf_counter()
        collector = RegionFigures(metrics_config.class_names, metrics_config.dist_th_tp, CURVE_REGIONS)
        reports[method] = evaluate(db, split, results, metrics_config, REGIONS, inspect=collector.collect)
        duplicates[method] = collector.duplicates
        key_at_tp = detail_key(TABLE_CLASS, metrics_config.dist_th_tp)
        curves_at_tp[method] = {region: curves[key_at_tp] for region, curves in collector.curves.items()}
        timings[f"metrics_{method}_s"] = time.perf_counter() - started
        write_report(out / f"metrics_{method}.json", reports[method], overwrite=True)
        write_details(out / f"metrics_details_{method}.json", collector.curves, overwrite=True)
        progress.advance()
    bases = {split_name(m)[0] for m in methods}
    reid = reidentification(boxes, gated=GATED_SIANMS in bases) if bases & {*MATCHERS, HYBRID} else {}
    table = eval_table(reports, reid, counts, duplicates)
    started = time.perf_counter()
    cache_config = complete_manifest(config.cache)["config"]
    dis_thr = choose_dis_thr(config.cache, cache_config, models.encoder, models.margins_midpoint)
    own_choices = thresholds_record(resolved, cache_config, dis_thr, table)
    timings["thresholds_s"] = time.perf_counter() - started
    if calibration is not None:
        table["best_nms"] = calibrated_best(table, calibration)
    table["thresholds"] = thresholds_used(resolved, table, calibration, config.dis_thr is not None)
    write_json(out / THRESHOLDS_FILE, own_choices)
    draw_pr_curves(out / "pr_curves.png", curves_at_tp, TABLE_CLASS, CURVE_REGIONS)
    write_json(out / "table.json", table)
    write_text(out / "table.md", table_markdown(table))
    started = time.perf_counter()
    pictures = draw_pictures(db, config, out, boxes, split.sample_tokens,
                             next(iter(reports.values())).cfg.class_names)
    timings["pictures_s"] = time.perf_counter() - started
    return table, pictures


def draw_pictures(db: NuScenesDB, config, out: Path, boxes: AllBoxes, sample_tokens, classes) -> list[str]:
    """``pictures/<sample>.png`` for the samples :func:`~sianms_cli.reporting.eval_pictures.pick_samples` picks;
    their file names."""
    from sianms_cli.reporting.eval_pictures import draw_sample, pick_samples

    shown = [m for m in PICTURE_METHODS if m in config.method_names] or list(config.method_names[:4])
    selections = {method: select(boxes, method, config.axis_mode) for method in shown}
    names = []
    for sample in pick_samples(boxes, config.pictures):
        names.append(f"{sample_tokens[sample]}.png")
        draw_sample(out / "pictures" / names[-1], db, sample_tokens[sample], sample, boxes, selections, tuple(classes))
    return names
