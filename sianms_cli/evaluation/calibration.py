"""Thresholds chosen on a calibration split, away from the split a table reports.

Every threshold of `sianms eval` (siaNMS's ``dis_thr``, the IoU of each NMS family) is a choice
made on labelled data, and chosen on the split the table reports it favours whichever method has
the most freedom (docs/methods.md#thresholds-from-a-calibration-split). So every evaluation
writes ``thresholds.json``, the choices **its own split** makes (:func:`thresholds_record`), and
an evaluation given ``--thresholds-from CALIB`` (a complete evaluation of *other scenes* of the
same world, detector and networks) takes every threshold from CALIB's file instead:

- ``dis_thr``: the matching F1 criterion of `sianms train siamese`'s validation
  (:func:`choose_dis_thr`), run on the calibration split's cache;
- each IoU NMS family: the variant with the best car AP over the calibration split, as
  ``best_nms`` of its table.json; circle NMS has no threshold and the hybrid's NMS stays the
  paper's IoU 0.3.

The calibration is refused (one error line) when it shares a scene with the evaluated split, or
was made on another dataset, detector, cache settings or networks (:func:`check_calibration`).
The evaluation records where each threshold came from (:func:`thresholds_used`), the
calibration by its path, split and the SHA-256 of its thresholds.json.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.io import read_json, sha256_of
from sianms_cli.json_stream import is_finite_number
from sianms_cli.evaluation.methods import IOU_METHODS, PAPER_NMS_IOU, split_name

THRESHOLDS_FILE = "thresholds.json"
KIND = "sianms-thresholds"
SCHEMA_VERSION = 1
EVAL_KIND = "sianms-eval"  # evaluation.job.KIND, not imported: job imports this module

CHOSEN_ON_FIELDS = ("version", "split", "split_scenes", "dataset_sha256", "cache_sha256", "siamese_sha256",
                    "fpointnet_sha256", "sianms_classes", "max_distance", "axis_mode", "nms_sweep", "methods")
"""What thresholds.json records of the evaluation that made its choices (eval.json's resolved config)."""
MUST_MATCH = ("version", "dataset_sha256", "siamese_sha256", "fpointnet_sha256", "sianms_classes", "max_distance",
              "axis_mode")
"""Fields a calibration must share with the evaluation that takes its thresholds: the same world, networks and
matching rules; only the scenes differ."""
PREPARE_FIELDS = ("detector", "detector_sha256", "backbone", "weights", "classes", "iou_threshold", "roi_size",
                  "sampling_ratio", "sweeps", "min_depth", "max_depth")
"""The cache settings that decide which detections, features and frustums an evaluation sees; a calibration's
cache must share them (its split, seed and --fill-missed may differ)."""
DIS_THR_CRITERION = ("matching F1 against ground-truth identity among each camera pair's overlap candidates "
                     "(`sianms train siamese`'s validation criterion)")
NMS_CRITERION = "best car AP over the split (region all)"


# --------------------------------------------------------------------------- the choices a split makes


def choose_dis_thr(cache: str | Path, cache_config: Mapping[str, Any], encoder: Any, default: float
                   ) -> dict[str, Any]:
    """The ``dis_thr`` the cache's split chooses by :data:`DIS_THR_CRITERION`, and its figures.

    ``encoder`` (the siamese run's) embeds every detection of the cache, scene by scene; the
    candidates are the detections in each contiguous pair's overlap, and the threshold is
    :func:`~sianms_cli.training.siamese.best_threshold`'s from ``default`` (the run's
    :func:`margins_midpoint`), exactly as the training's validation. No choice (``value`` None, and
    why) for a cache whose missed objects were filled in from the ground truth (the F1 would count
    boxes no detector gave) or without one ground-truth pair among the candidates.
    """
    if cache_config.get("fill_missed"):
        return {"value": None, "why": "the cache's missed objects were filled in from the ground truth "
                                      "(`sianms prepare --fill-missed`); prepare the split with --no-fill-missed"}
    from sianms_cli.data.siamese import iter_scenes
    from sianms_cli.training.siamese import best_threshold, embed_scene, scene_groups

    groups = []
    for scene in iter_scenes(cache):
        groups += scene_groups(scene, embed_scene(encoder, scene, next(encoder.parameters()).device))
    pairs_true = sum(int(group.match_same.sum()) for group in groups)
    if pairs_true == 0:
        return {"value": None, "why": "no ground-truth pair among the overlap candidates: the F1 is undefined"}
    value, scores = best_threshold(groups, default)
    return {"value": value, "f1": _finite(scores["f1"]), "precision": _finite(scores["precision"]),
            "recall": _finite(scores["recall"]), "pairs_true": pairs_true, "criterion": DIS_THR_CRITERION}


def margins_midpoint(config: Any, stored: float) -> float:
    """(α + β) / 2 of a siamese run's config, where its validation's threshold search starts; its stored
    ``dis_thr`` for a config without both margins."""
    alpha, beta = (config.get(name) if isinstance(config, dict) else None for name in ("alpha", "beta"))
    return (alpha + beta) / 2 if is_finite_number(alpha) and is_finite_number(beta) else stored


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def nms_choices(table: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """{family: {method, iou, car_ap}} of each IoU NMS family's best variant in a table.json (its ``best_nms``)."""
    out = {}
    for family, method in table["best_nms"].items():
        cell = table["regions"]["all"][method][table["table_class"]]
        out[family] = {"method": method, "iou": split_name(method)[1], "car_ap": cell["AP"],
                       "criterion": NMS_CRITERION}
    return out


def thresholds_record(resolved: Mapping[str, Any], cache_config: Mapping[str, Any], dis_thr: Mapping[str, Any],
                      table: Mapping[str, Any]) -> dict[str, Any]:
    """thresholds.json's content: the choices of the evaluation of ``resolved`` (its eval.json config) on its split."""
    return {"kind": KIND, "schema_version": SCHEMA_VERSION,
            "chosen_on": {**{name: resolved.get(name) for name in CHOSEN_ON_FIELDS},
                          "prepare": {name: cache_config.get(name) for name in PREPARE_FIELDS}},
            "dis_thr": dict(dis_thr), "nms": nms_choices(table)}


# --------------------------------------------------------------------------- taking them from a calibration


@dataclass(frozen=True)
class Calibration:
    """A calibration evaluation's thresholds.json, read and checked.

    Attributes:
        folder: the evaluation folder given to ``--thresholds-from``.
        record: the file's content; sha256: the file's fingerprint.
    """

    folder: Path
    record: dict[str, Any]
    sha256: str

    @property
    def chosen_on(self) -> dict[str, Any]:
        return self.record["chosen_on"]

    @property
    def dis_thr(self) -> float | None:
        return self.record["dis_thr"]["value"]

    @property
    def identity(self) -> dict[str, Any]:
        """What eval.json's config records of it: by content, so a moved calibration is the same one."""
        return {"split": self.chosen_on["split"], "sha256": self.sha256}

    def source(self) -> dict[str, Any]:
        """The calibration as the evaluation's outputs name it: path, split, its scenes and fingerprint."""
        return {"path": str(self.folder), "split": self.chosen_on["split"],
                "split_scenes": list(self.chosen_on["split_scenes"]), "sha256": self.sha256}


def read_calibration(folder: str | Path) -> Calibration:
    """The thresholds of a complete evaluation folder (``--thresholds-from``), each field checked.

    Raises:
        DataFormatError: naming the file and field: not a complete `sianms eval` folder, or a
            thresholds.json missing (an evaluation from before the file existed) or malformed.
    """
    folder = Path(folder)
    marker_path = folder / "eval.json"
    if not folder.is_dir():
        raise DataFormatError(folder, "not a folder; --thresholds-from takes a `sianms eval` output folder")
    marker = read_json(marker_path)
    if not isinstance(marker, dict) or marker.get("kind") != EVAL_KIND:
        raise DataFormatError(marker_path, f"not a sianms evaluation: expected '{EVAL_KIND}'", field="kind")
    if marker.get("complete") is not True:
        raise DataFormatError(marker_path, "the calibration evaluation is not complete; finish it with `sianms eval` "
                                           "first", field="complete")
    path = folder / THRESHOLDS_FILE
    if not path.is_file():
        raise DataFormatError(path, "not found: the evaluation predates thresholds.json; rerun it with --overwrite, "
                                    "which redoes its finish stage and keeps its scenes")
    record = read_json(path)
    _check_record(record, path)
    return Calibration(folder, record, sha256_of(path))


def _check_record(record: Any, path: Path) -> None:
    if not isinstance(record, dict) or record.get("kind") != KIND:
        raise DataFormatError(path, f"not a sianms thresholds file: expected '{KIND}'", field="kind")
    if record.get("schema_version") != SCHEMA_VERSION:
        raise DataFormatError(path, f"this sianms reads version {SCHEMA_VERSION}, got {record.get('schema_version')!r}",
                              field="schema_version")
    chosen_on = record.get("chosen_on")
    if not isinstance(chosen_on, dict):
        raise DataFormatError(path, "must be an object", field="chosen_on")
    for name in (*CHOSEN_ON_FIELDS, "prepare"):
        if name not in chosen_on:
            raise DataFormatError(path, "missing", field=f"chosen_on.{name}")
    scenes = chosen_on["split_scenes"]
    if not (isinstance(scenes, list) and scenes and all(isinstance(scene, str) for scene in scenes)):
        raise DataFormatError(path, "must be a non-empty list of scene names", field="chosen_on.split_scenes")
    if not isinstance(chosen_on["split"], str):
        raise DataFormatError(path, "must be a split name", field="chosen_on.split")
    if not isinstance(chosen_on["prepare"], dict):
        raise DataFormatError(path, "must be an object", field="chosen_on.prepare")
    dis_thr = record.get("dis_thr")
    if not isinstance(dis_thr, dict) or "value" not in dis_thr:
        raise DataFormatError(path, "must be an object with a value", field="dis_thr")
    value = dis_thr["value"]
    if value is not None and not (is_finite_number(value) and value > 0):
        raise DataFormatError(path, f"must be a finite number > 0 or null, got {value!r}", field="dis_thr.value")
    nms = record.get("nms")
    if not isinstance(nms, dict):
        raise DataFormatError(path, "must be an object", field="nms")
    for family, choice in nms.items():
        method = choice.get("method") if isinstance(choice, dict) else None
        try:
            base = split_name(method)[0] if isinstance(method, str) else None
        except ValueError:  # "axis-nms@x"
            base = None
        if family not in IOU_METHODS or base != family:
            raise DataFormatError(path, f"must name a variant of one of {', '.join(IOU_METHODS)}, got {method!r}",
                                  field=f"nms.{family}.method")


def check_calibration(calibration: Calibration, resolved: Mapping[str, Any], cache_config: Mapping[str, Any],
                      matchers_evaluated: bool) -> None:
    """Refuse a calibration an evaluation of ``resolved`` (its eval.json config, before the thresholds are
    taken) may not take its thresholds from.

    Raises SianmsError naming ``--thresholds-from``: a scene shared with the evaluated split; another
    dataset, networks, matching rules or cache settings; no ``dis_thr`` where a matcher is evaluated; an
    IoU NMS family evaluated here that the calibration did not, or whose chosen variant is not among
    this evaluation's methods.
    """
    where = f"--thresholds-from: {calibration.folder}"
    chosen_on = calibration.chosen_on
    shared = [scene for scene in chosen_on["split_scenes"] if scene in set(resolved["split_scenes"])]
    if shared:
        raise SianmsError(f"{where} was evaluated on split '{chosen_on['split']}', which shares {len(shared)} "
                          f"scene(s) with --split {resolved['split']} ({', '.join(shared[:3])}"
                          f"{', ...' if len(shared) > 3 else ''}): thresholds must be chosen on other scenes")
    differing = [name for name in MUST_MATCH if chosen_on.get(name) != resolved.get(name)]
    differing += [f"prepare {name}" for name in PREPARE_FIELDS
                  if chosen_on["prepare"].get(name) != cache_config.get(name)]
    if differing:
        raise SianmsError(f"{where} was made on another dataset, cache settings or networks (differs in: "
                          f"{', '.join(differing)}); calibrate on other scenes of the same world with the same "
                          "detector, cache settings and runs")
    if matchers_evaluated and calibration.dis_thr is None:
        raise SianmsError(f"{where} chose no dis_thr ({calibration.record['dis_thr'].get('why', 'no reason given')})")
    methods = list(resolved["methods"])
    for family in dict.fromkeys(split_name(method)[0] for method in methods if split_name(method)[0] in IOU_METHODS):
        choice = calibration.record["nms"].get(family)
        if choice is None:
            raise SianmsError(f"{where} did not evaluate {family}, so it chose no threshold for it; evaluate the "
                              "calibration split with the same --methods")
        if choice["method"] not in methods:
            raise SianmsError(f"--nms-sweep: the calibration chose {choice['method']}, which this evaluation does not "
                              f"run; give the calibration's sweep ({chosen_on['nms_sweep']}) or leave --nms-sweep out")


def thresholds_used(resolved: Mapping[str, Any], table: Mapping[str, Any], calibration: Calibration | None,
                    dis_thr_flag: bool) -> dict[str, Any]:
    """table.json's ``thresholds``: each threshold the evaluation used and where it came from.

    Args:
        resolved: the evaluation's eval.json config (its ``dis_thr`` is the one used).
        table: its table, whose ``best_nms`` is the variants reported as each family's best.
        calibration: the ``--thresholds-from`` evaluation, or None.
        dis_thr_flag: ``--dis-thr`` was given.
    """
    if calibration is not None:
        nms_source = "calibration"
        dis_thr_source = ("calibration" if calibration.dis_thr is not None
                          else "siamese checkpoint (the calibration chose none; no matcher evaluated)")
    else:
        dis_thr_source = "--dis-thr" if dis_thr_flag else "siamese checkpoint"
        nms_source = "this split"
    return {"dis_thr": {"value": resolved["dis_thr"], "source": dis_thr_source},
            "nms": {family: {"method": method, "iou": split_name(method)[1], "source": nms_source}
                    for family, method in table["best_nms"].items()},
            "hybrid_nms_iou": PAPER_NMS_IOU,
            "calibration": None if calibration is None else calibration.source()}


def calibrated_best(table: Mapping[str, Any], calibration: Calibration) -> dict[str, str]:
    """``best_nms`` for an evaluation with ``--thresholds-from``: each family's variant chosen on the calibration
    split, for the families this table evaluated (:func:`check_calibration` made sure each is among its methods)."""
    families = {split_name(method)[0] for method in table["methods"]}
    return {family: choice["method"] for family, choice in calibration.record["nms"].items() if family in families}
