"""`sianms eval`: every duplicate-handling method on one split, end to end to Table I.

Two stages under ``out``:

1. **Scenes** (the expensive one, resumable): for each scene of the split, the cache's shard
   goes through :class:`~.scene.SceneEvaluator` and its boxes table is written atomically to
   ``scenes/<scene>.parquet``. A finished scene is never recomputed, so a killed run reruns
   only what is missing; runs with ``--shard K/N`` split the scenes between them and
   cooperate scene by scene (a lock per scene, as ``prepare``).
2. **Finish** (seconds, whenever every scene is done): each method's selection
   (:mod:`.methods`) becomes ``results_<method>.json`` (nuScenes submission format), is
   scored with the ``paper`` metrics config in the regions all, overlap and per camera pair
   (``metrics_<method>.json``, the data class ``sianms metrics`` writes), and the comparison
   is written as ``table.md`` / ``table.json`` (:mod:`sianms_cli.reporting.eval_table`).

``eval.json`` holds the resolved config, the inputs' fingerprints, the scenes done and the
timings; its ``complete`` is true only once the finish stage has written every output.

Predictions carry what Frustum PointNets does not estimate as MMDetection3D fills it for a
model without a velocity head: velocity (0, 0), and the class's default attribute for a
box that does not move (``NuScenesDataset._format_bbox``: car ``vehicle.parked``,
pedestrian ``pedestrian.standing``, bicycle and motorcycle ``cycle.without_rider``, bus
``vehicle.stopped``). The paper's metrics (AP, ATE, ASE, AOE) use neither.
"""

from __future__ import annotations

import math
import re
import shutil
import time
from contextlib import closing
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generator

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from sianms_cli.data.cache import cache_fingerprint, checked_files, trust_checked_files, verified_shard, verify_cache
from sianms_cli.detection2d.classes import check_classes
from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError, check_seed, check_workers
from sianms_cli.geometry.bev import AXIS_MODES
from sianms_cli.io import (atomic_file, exclusive_lock, make_folder, partial_of, read_json, release_lock,
                           try_lock, write_json)
from sianms_cli.nuscenes.fingerprint import dataset_fingerprint
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.evaluation.calibration import Calibration, check_calibration, margins_midpoint, read_calibration
from sianms_cli.evaluation.finish import broken_rows, finish
from sianms_cli.evaluation.inference import FPointNetPredictor
from sianms_cli.evaluation.methods import (HYBRID, IOU_METHODS, MATCHERS, METHODS, parse_methods, parse_thresholds,
                                          split_name)
from sianms_cli.evaluation.scene import SceneEvaluator, SceneSettings
from sianms_cli.prepare.job import parse_shard, split_scenes
from sianms_cli.processes import TASK_TORCH_THREADS, task_torch_threads, worker_pool
from sianms_cli.progress import SILENT, Progress
from sianms_cli.reporting.report import DEFAULT_FOLDER as REPORT_FOLDER, foreign_entry, is_report_folder

if TYPE_CHECKING:
    from sianms_cli.models.siamese import SiameseEncoder

MARKER = "eval.json"
SCENES = "scenes"
PICTURES = "pictures"
LOCK = ".eval.lock"
KIND = "sianms-eval"
# The files the finish stage writes beside eval.json (curves.json: before metrics_details_<method>.json).
_METHOD = "|".join([*map(re.escape, METHODS), *(rf"{re.escape(name)}@[0-9.e+-]+" for name in IOU_METHODS)])
_EVAL_FILE = re.compile(rf"(?:results|metrics|metrics_details)_(?:{_METHOD})\.json|table\.json|table\.md|pr_curves\.png"
                        r"|curves\.json|thresholds\.json")


@dataclass(frozen=True)
class EvalConfig:
    """What `sianms eval` does (module docstring); every field is a flag."""

    dataroot: str
    version: str
    split: str
    cache: str
    siamese: str
    fpointnet: str
    methods: str = "all"
    nms_sweep: str | None = None
    axis_mode: str = "ignore-yaw"
    sianms_classes: tuple[str, ...] = ("car",)
    dis_thr: float | None = None  # None: the siamese checkpoint's
    max_distance: float = 50.0  # nuScenes' detection range for cars (detection_cvpr_2019 class_range)
    seed: int = 0
    device: str = "cpu"
    pictures: int = 4  # samples drawn in bird's-eye view (the most ground-truth duplicates first)
    thresholds_from: str | None = None  # a calibration evaluation folder: every threshold from its split (.calibration)

    def __post_init__(self) -> None:
        object.__setattr__(self, "sianms_classes", tuple(self.sianms_classes))
        self.method_names  # validates --methods and --nms-sweep
        if self.axis_mode not in AXIS_MODES:
            raise SianmsError(f"--axis-mode must be one of {', '.join(AXIS_MODES)}, got '{self.axis_mode}'")
        if not self.sianms_classes:
            raise SianmsError("--sianms-classes must name at least one class")
        try:
            check_classes(self.sianms_classes)
        except SianmsError as error:
            raise SianmsError(f"--sianms-classes: {error}") from None
        if self.dis_thr is not None and not (math.isfinite(self.dis_thr) and self.dis_thr > 0):
            raise SianmsError(f"--dis-thr must be a finite number > 0, got {self.dis_thr}")
        if self.thresholds_from is not None and self.dis_thr is not None:
            raise SianmsError("--dis-thr: --thresholds-from sets dis_thr from the calibration split; give one of them")
        if self.thresholds_from is not None and not str(self.thresholds_from).strip():
            raise SianmsError("--thresholds-from: must not be empty")
        if self.pictures < 0:
            raise SianmsError(f"--pictures must be >= 0, got {self.pictures}")
        if not (math.isfinite(self.max_distance) and self.max_distance > 0):
            raise SianmsError(f"--max-distance must be a finite number > 0, got {self.max_distance}")
        check_seed(self.seed)

    @property
    def method_names(self) -> tuple[str, ...]:
        return parse_methods(self.methods, parse_thresholds(self.nms_sweep))


@dataclass
class EvalResult:
    """What one run did, and the outputs when the evaluation is complete."""

    out: Path
    manifest: dict[str, Any]
    scenes_run: list[str] = field(default_factory=list)
    scenes_skipped: list[str] = field(default_factory=list)
    scenes_busy: list[str] = field(default_factory=list)
    table: dict[str, Any] | None = None


# --------------------------------------------------------------------------- inputs


EVAL_DATASETS = ("detections", "frustums")  # the cache's datasets eval reads: checked whole at its start


def cache_settings(cache: Path, db: NuScenesDB, split: str, scenes: list[str]) -> dict[str, Any]:
    """The cache's resolved prepare config, checked to be a complete cache of this dataset's split whose
    folder holds what its manifest lists (:func:`~sianms_cli.data.cache.verify_cache`)."""
    config = verify_cache(cache, EVAL_DATASETS)["config"]
    where = cache / "manifest.json"
    if config.get("dataset_sha256") != dataset_fingerprint(db.table_root):
        raise DataFormatError(where, "the cache was prepared from another dataset than --dataroot/--version",
                              field="config.dataset_sha256")
    if list(config.get("split_scenes", [])) != scenes:
        raise DataFormatError(where, f"the cache holds split '{config.get('split')}', not --split {split}",
                              field="config.split_scenes")
    return config


def scene_settings(config: EvalConfig, cache_config: dict[str, Any], dis_thr: float) -> SceneSettings:
    max_depth = cache_config.get("max_depth")
    return SceneSettings(
        matched_classes=config.sianms_classes, dis_thr=dis_thr, max_distance=config.max_distance, seed=config.seed,
        sweeps=int(cache_config.get("sweeps", 0)), min_depth=float(cache_config.get("min_depth", 1.0)),
        max_depth=float("inf") if max_depth is None else float(max_depth))


@dataclass(frozen=True, eq=False)
class Models:
    """The trained runs, each checkpoint read once.

    Attributes:
        predictor: Frustum PointNets; encoder: the siamese encoder; dis_thr: the matching
        threshold (``--dis-thr`` or the siamese run's); siamese_sha256, fpointnet_sha256: the
        checkpoints' fingerprints of content (:func:`~sianms_cli.training.run.checkpoint_fingerprint`);
        margins_midpoint: where the siamese run's threshold search starts (:func:`.calibration.choose_dis_thr`).
    """

    predictor: FPointNetPredictor
    encoder: SiameseEncoder
    dis_thr: float
    siamese_sha256: str
    fpointnet_sha256: str
    margins_midpoint: float


def load_models(config: EvalConfig) -> Models:
    """The trained runs of ``config`` on its device (checked first), each checkpoint read once."""
    from sianms_cli.training.run import checkpoint_file, checkpoint_fingerprint, choose_device, load_checkpoint
    from sianms_cli.training.siamese import encoder_from_checkpoint

    device = str(choose_device(config.device))
    siamese_path, fpointnet_path = checkpoint_file(config.siamese), checkpoint_file(config.fpointnet)
    siamese, fpointnet = load_checkpoint(siamese_path, "siamese"), load_checkpoint(fpointnet_path, "fpointnet")
    encoder, dis_thr = encoder_from_checkpoint(siamese, siamese_path, device)
    return Models(predictor=FPointNetPredictor(fpointnet, fpointnet_path, device), encoder=encoder,
                  dis_thr=float(config.dis_thr if config.dis_thr is not None else dis_thr),
                  siamese_sha256=checkpoint_fingerprint(siamese), fpointnet_sha256=checkpoint_fingerprint(fpointnet),
                  margins_midpoint=margins_midpoint(siamese.config, dis_thr))


def check_feature_shape(cache: Path, encoder_shape: tuple[int, int, int], siamese: str) -> None:
    """Refuse, before anything is written, a cache whose ROI features the siamese encoder of the run
    ``siamese`` cannot take (another backbone or --roi-size than its training cache's)."""
    from sianms_cli.data.siamese import cache_feature_shape
    from sianms_cli.training.run import checkpoint_file

    checkpoint = checkpoint_file(siamese)
    shape = cache_feature_shape(cache)
    if shape != tuple(encoder_shape):
        raise DataFormatError(cache / "manifest.json", f"ROI features of shape {shape}, but the siamese encoder of "
                              f"{checkpoint} takes {tuple(encoder_shape)}: prepare the cache with the backbone and "
                              "--roi-size of its training cache", field="config.roi_size")


# Fields that decide only which boxes each method reports (the calibration's dis_thr is in "dis_thr").
FINISH_FIELDS = ("methods", "nms_sweep", "axis_mode", "pictures", "thresholds_from")


def resolved_config(config: EvalConfig, db: NuScenesDB, scenes: list[str], models: Models,
                    calibration: Calibration | None = None) -> dict[str, Any]:
    """The config as eval.json records it: inputs by content (dataset, cache, checkpoints, the calibration's
    thresholds.json), so the same inputs in other folders give the same config.

    The fields of :data:`FINISH_FIELDS` do not change the scenes' boxes tables, so an
    ``--overwrite`` that changes only them keeps the scenes and redoes the finish stage.
    """
    data = asdict(config)
    for name in ("dataroot", "cache", "siamese", "fpointnet", "device", "thresholds_from"):
        del data[name]
    if calibration is not None:  # absent otherwise, so evaluations from before the flag keep their config
        data["thresholds_from"] = calibration.identity
    data.update(sianms_classes=list(config.sianms_classes), dis_thr=models.dis_thr, methods=list(config.method_names),
                dataset_sha256=dataset_fingerprint(db.table_root), split_scenes=scenes,
                cache_sha256=cache_fingerprint(verify_cache(config.cache, EVAL_DATASETS)),
                siamese_sha256=models.siamese_sha256, fpointnet_sha256=models.fpointnet_sha256)
    return data


# --------------------------------------------------------------------------- the output folder


def scene_part(resolved: dict[str, Any]) -> dict[str, Any]:
    """The part of a resolved config the scenes' boxes tables depend on."""
    return {key: value for key, value in resolved.items() if key not in FINISH_FIELDS}


def claim_output(out: Path, resolved: dict[str, Any], overwrite: bool) -> bool:
    """Make ``out`` this evaluation's folder, or check that it is (under the folder lock).

    A folder with another evaluation's ``eval.json`` is replaced only with ``overwrite``, which
    also redoes this evaluation's own (keeping the scenes when they are this config's: a damaged
    table.json is written anew), and only when everything in it is
    something `sianms eval` writes (:func:`_is_eval_entry`: a stale report folder counts); a
    non-empty folder without one is never touched. Returns whether ``out`` already holds this
    evaluation, complete.
    """
    marker = out / MARKER
    entries = refuse_foreign_folder(out)
    if marker.is_file():
        stored = read_json(marker)
        if not isinstance(stored, dict) or stored.get("kind") != KIND:
            raise OutputExistsError(f"{marker} is not a sianms evaluation's; choose another --out")
        if not isinstance(stored.get("config"), dict):
            raise DataFormatError(marker, f"must be an object, got {type(stored.get('config')).__name__}",
                                  field="config")
        if stored.get("config") != resolved and not overwrite:
            differing = sorted(k for k in set(resolved) | set(stored.get("config", {}))
                               if resolved.get(k) != stored.get("config", {}).get(k))
            raise OutputExistsError(f"{out} holds an evaluation with another config (differs in: "
                                    f"{', '.join(differing)}); pass --overwrite or choose another --out")
        if overwrite:  # another config's evaluation, or this one's redone (a damaged table.json)
            keep_scenes = scene_part(stored.get("config", {})) == scene_part(resolved)
            stale = sorted(entry for entry in entries
                           if entry.name != MARKER and not (keep_scenes and entry.name == SCENES))
            foreign = _first_foreign(out, stale, stored)  # all checked before anything is deleted
            if foreign is not None:
                raise OutputExistsError(f"{out}: not replaced: '{foreign.relative_to(out)}' is not something "
                                        "sianms eval writes; remove it yourself or choose another --out")
            # Unfinished first: a kill among the deletions leaves an evaluation a rerun resumes,
            # not one that says "complete" over deleted files.
            write_json(marker, {**stored, "complete": False})
            for entry in stale:
                shutil.rmtree(entry) if entry.is_dir() else entry.unlink()
        elif stored.get("complete") is True:  # an edited "yes" is not a finished evaluation: resume it
            return True
    write_marker(out, resolved, {}, complete=False)  # before the scenes' folder: a folder without it is not eval's
    make_folder(out / SCENES)
    return False


FINISH_AGAIN = "rerun with --overwrite, which redoes the finish stage and keeps the scenes"


def _finished_table(out: Path) -> dict[str, Any]:
    """A complete evaluation's table.json; a damaged one, or a missing table.md, is named with what to do."""
    if not (out / "table.md").is_file():
        raise DataFormatError(out / "table.md", f"missing from a complete evaluation; {FINISH_AGAIN}")
    try:
        return read_json(out / "table.json")
    except DataFormatError as error:
        raise DataFormatError(error.path, f"{error.detail}; {FINISH_AGAIN}", token=error.token,
                              field=error.field) from None


def _first_foreign(out: Path, entries: list[Path], stored: dict[str, Any]) -> Path | None:
    """The first of ``entries`` of the evaluation folder ``out`` (whose eval.json holds ``stored``), or of
    what they hold, that `sianms eval` does not write (:func:`_is_eval_entry`), or None."""
    inside = [child for entry in entries if entry.name in (SCENES, PICTURES) and _is_eval_entry(entry)
              for child in sorted(entry.iterdir())]
    config = stored.get("config")
    scenes = config.get("split_scenes") if isinstance(config, dict) else None
    scenes = frozenset(name for name in scenes if isinstance(name, str)) if isinstance(scenes, list) else frozenset()
    pictures = stored.get("pictures")
    pictures = frozenset(name for name in pictures if isinstance(name, str)) if isinstance(pictures, list) else None
    return next((entry for entry in entries + inside
                 if not _is_eval_entry(entry, "" if entry.parent == out else entry.parent.name, scenes, pictures)),
                None)


def foreign_eval_entry(out: Path) -> Path | None:
    """The first path in an evaluation folder that `sianms eval` does not write, or None: what deleting
    the folder would take of someone else's (a folder without eval.json is all someone else's)."""
    stored = read_json(out / MARKER) if (out / MARKER).is_file() else None
    if not isinstance(stored, dict) or stored.get("kind") != KIND:
        return out
    return _first_foreign(out, sorted(entry for entry in out.iterdir() if entry.name != MARKER), stored)


def refuse_foreign_folder(out: Path) -> list[Path]:
    """The entries of ``out`` but the lock; refuses a non-empty folder without an ``eval.json``.

    Checked before the folder lock is taken too, so a refused folder does not get a lock file."""
    entries = [entry for entry in out.iterdir() if entry.name != LOCK] if out.is_dir() else []
    if entries and not (out / MARKER).is_file():
        raise OutputExistsError(f"{out} is not empty and is not a sianms evaluation (no {MARKER}); "
                                "choose another --out")
    return entries


def _is_eval_entry(entry: Path, folder: str = "", scenes: frozenset[str] = frozenset(),
                   pictures: frozenset[str] | None = None) -> bool:
    """Whether an entry of an evaluation folder (of its subfolder ``folder``: scenes, pictures) is one
    `sianms eval` writes there, a killed write's temporary file of one, or `sianms report`'s default
    report folder: what ``--overwrite`` may delete. In ``scenes`` only the tables and locks of the
    evaluation's own scenes (``scenes``: its split's) are, in ``pictures`` only the pictures its
    eval.json lists (any .png of a run that stopped before it listed them); links never are."""
    if entry.is_symlink():
        return False
    partial = partial_of(entry.name)
    name = partial or entry.name
    if entry.is_file():
        if folder == SCENES:
            stem, _, extension = name.rpartition(".")
            return extension in ("parquet", "lock") and stem in scenes
        if folder:
            return folder == PICTURES and name.endswith(".png") and (pictures is None or name in pictures)
        return name in (MARKER, LOCK) or _EVAL_FILE.fullmatch(name) is not None
    if not entry.is_dir() or partial or folder:
        return False
    return name in (SCENES, PICTURES) or (name == REPORT_FOLDER and is_report_folder(entry)
                                           and foreign_entry(entry) is None)


def write_marker(out: Path, resolved: dict[str, Any], extra: dict[str, Any], *, complete: bool) -> dict[str, Any]:
    scenes = resolved["split_scenes"]
    done = [name for name in scenes if (out / SCENES / f"{name}.parquet").is_file()]
    marker = {"kind": KIND, "config": resolved, "complete": complete, "scenes_expected": len(scenes),
              "scenes_finished": len(done), "missing_scenes": [name for name in scenes if name not in done], **extra}
    write_json(out / MARKER, marker)
    return marker


def scene_path(out: Path, name: str) -> Path:
    return out / SCENES / f"{name}.parquet"


NETWORK_FIELDS = ("translation", "size", "yaw")  # a box's fields that Frustum PointNets estimates


def refuse_broken_boxes(table: pa.Table, checkpoint: Path, scene: str) -> None:
    """Refuse, before it is written, a scene's boxes table that the finish stage would refuse: its boxes come
    from the F-PointNets checkpoint, which is named (weights beyond float32's range give infinite boxes);
    once written, the message would blame the scene's table, and its deletion would not help."""
    for name, broken, expected in broken_rows(table):
        rows = np.flatnonzero(broken)
        if name in NETWORK_FIELDS and len(rows):
            raise DataFormatError(checkpoint, f"the network gave scene {scene} a box whose {name} is not "
                                              f"{expected} (row {rows[0]}): the checkpoint is not usable; take "
                                              "another one or train again")


def write_scene(evaluator: SceneEvaluator, cache: Path, out: Path, token: str, name: str) -> str:
    """Evaluate one scene unless it is done or another run holds it: "written", "finished", "busy"."""
    lock = try_lock(out / SCENES / f"{name}.lock")
    if lock is None:
        return "busy"
    try:
        path = scene_path(out, name)
        if path.is_file():
            return "finished"
        table = evaluator.scene(verified_shard(cache, "detections", name), verified_shard(cache, "frustums", name),
                                token)
        refuse_broken_boxes(table, evaluator.predictor.path, name)
        with atomic_file(path) as handle:
            pq.write_table(table, handle, compression="zstd")
        return "written"
    finally:
        release_lock(lock)


# --------------------------------------------------------------------------- workers

_WORKER: tuple[SceneEvaluator, Path, Path] | None = None


def _init_worker(config: EvalConfig, settings: SceneSettings, out: str, checked: set[tuple]) -> None:
    global _WORKER
    import torch

    trust_checked_files(checked)  # the parent read and checked the cache's files at its start
    torch.set_num_threads(TASK_TORCH_THREADS)
    models = load_models(config)
    db = NuScenesDB(config.dataroot, config.version)
    _WORKER = (SceneEvaluator(db, models.predictor, models.encoder, settings), Path(config.cache), Path(out))


def _run_in_worker(args: tuple[str, str]) -> tuple[str, str]:
    token, name = args
    assert _WORKER is not None
    evaluator, cache, out = _WORKER
    return name, write_scene(evaluator, cache, out, token, name)


def _run_scenes(evaluator: SceneEvaluator, config: EvalConfig, settings: SceneSettings, out: Path,
                todo: list[tuple[str, str]], workers: int) -> Generator[tuple[str, str], None, None]:
    if workers == 1 or len(todo) <= 1:
        with task_torch_threads():
            for token, name in todo:
                yield name, write_scene(evaluator, Path(config.cache), out, token, name)
        return
    with worker_pool(min(workers, len(todo)), _init_worker, (config, settings, str(out), checked_files())) as pool:
        yield from pool.imap_unordered(_run_in_worker, todo)


# --------------------------------------------------------------------------- entry point


def run(config: EvalConfig, out: str | Path, *, overwrite: bool = False, progress: Progress = SILENT,
        workers: int = 1, shard: str | None = None) -> EvalResult:
    """Evaluate every method of ``config`` into ``out`` (module docstring).

    Args:
        config: what to evaluate.
        out: the evaluation folder.
        overwrite: replace an evaluation of another config in ``out``.
        progress: told the scenes to do, then each one done.
        workers: processes for the scenes stage (the output does not depend on it).
        shard: "K/N": this run does the scenes whose position in the split is K mod N.
    """
    started = time.perf_counter()
    k, n = parse_shard(shard)
    check_workers(workers)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out} exists and is not a folder; choose another --out")
    refuse_foreign_folder(out)
    db = NuScenesDB(config.dataroot, config.version)
    scenes = split_scenes(db, config.split)
    names = [name for _, name in scenes]
    cache = Path(config.cache)
    cache_config = cache_settings(cache, db, config.split, names)
    calibration = None if config.thresholds_from is None else read_calibration(config.thresholds_from)
    if calibration is not None and config.nms_sweep is None:  # the calibration's sweep holds each family's choice
        config = replace(config, nms_sweep=calibration.chosen_on["nms_sweep"])
    models = load_models(config)
    check_feature_shape(cache, models.encoder.feature_shape, config.siamese)
    resolved = resolved_config(config, db, names, models, calibration)
    if calibration is not None:
        check_calibration(calibration, resolved, cache_config,
                          matchers_evaluated=any(split_name(m)[0] in (*MATCHERS, HYBRID) for m in config.method_names))
        if calibration.dis_thr is not None:
            models = replace(models, dis_thr=calibration.dis_thr)
            resolved["dis_thr"] = models.dis_thr
    settings = scene_settings(config, cache_config, models.dis_thr)
    with exclusive_lock(out / LOCK, what=str(out), blocking=True):
        if claim_output(out, resolved, overwrite):
            return EvalResult(out, read_json(out / MARKER), scenes_skipped=names, table=_finished_table(out))
    mine = [(token, name) for i, (token, name) in enumerate(scenes) if i % n == k]
    result = EvalResult(out, {})
    todo = [(token, name) for token, name in mine if not scene_path(out, name).is_file()]
    result.scenes_skipped = [name for _, name in mine if scene_path(out, name).is_file()]
    evaluator = SceneEvaluator(db, models.predictor, models.encoder, settings)
    progress.start(len(todo), "scene", "eval")
    outcomes = {"written": result.scenes_run, "finished": result.scenes_skipped, "busy": result.scenes_busy}
    try:
        with closing(_run_scenes(evaluator, config, settings, out, todo, workers)) as done:
            for name, outcome in done:
                outcomes[outcome].append(name)
                progress.advance()
    finally:
        with exclusive_lock(out / LOCK, what=str(out), blocking=True):
            result.manifest = write_marker(out, resolved, {}, complete=False)
    scenes_seconds = time.perf_counter() - started
    if result.manifest["missing_scenes"]:
        return result
    with exclusive_lock(out / LOCK, what=str(out), blocking=True):
        timings = {"scenes_s": scenes_seconds}
        result.table, pictures = finish(db, config, out, [scene_path(out, name) for name in names], timings, progress,
                                        resolved=resolved, calibration=calibration, models=models)
        result.manifest = write_marker(out, resolved, {"timings": timings, "pictures": pictures}, complete=True)
    return result

