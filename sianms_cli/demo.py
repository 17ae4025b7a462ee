"""`sianms demo`: the whole study in one command — synth → prepare → train → eval → report.

Each stage is the library call its own command makes, into a folder of its own under
``out``::

    out/demo.json        what was asked, each stage's state and wall time; "complete" once the report exists
    out/.demo.lock       held while a demo runs here: a second one is refused until it ends
    out/data/            `sianms synth` (v1.0-mini, or v1.0-trainval for a larger study)
    out/cache-train/     `sianms prepare --split mini_train` (train)
    out/cache-val/       `sianms prepare --split mini_val` (val)
    out/siamese/         `sianms train siamese`
    out/fpointnet/       `sianms train fpointnet`, only with ``train_fpointnet`` (else the zoo's detector)
    out/eval/            `sianms eval` (every method, the NMS sweep)
    out/eval/report/     `sianms report`: report.html, report.md, report.json

A stage recorded as done in ``demo.json`` (and whose folder is still there) is skipped, so a
killed demo reruns from the stage it was in; that stage resumes as its own command would
(prepare by shard, training from its last epoch's checkpoint, eval by scene). One seed drives
every random source: the world, the simulated 2-D detector, both trainings and eval's point
sampling, so seeds vary all of them together.

The two profiles (:data:`PROFILES`) size the study to the machine: the default fits 15
minutes on two CPU cores, ``--quick`` 3 minutes (what it changes is listed in
:data:`QUICK`). Both are far smaller than the paper's training (Frustum PointNets trains 201
epochs on 1,024 points in the original): a demo shows the mechanics and the direction of the
effects, and ``--scenes`` / ``--siamese-epochs`` / ``--fpointnet-epochs`` scale it up.
v1.0-mini caps a demo at its ten scenes, two of them validation; ``version="v1.0-trainval"``
takes any number of the devkit's trainval scene names, 150/850 of them validation (as
nuScenes), for a validation set large enough to rank the methods. The trainings run on the
CPU in float32 unless ``precision="bf16"`` (:mod:`sianms_cli.training.precision`), which is
faster on CPUs that compute bfloat16 natively and trains other weights.
"""

from __future__ import annotations

import os
import shutil
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, NamedTuple

from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError, check_epochs, check_seed, check_workers
from sianms_cli.io import exclusive_lock, make_folder, read_json, write_json
from sianms_cli.json_stream import is_finite_number
from sianms_cli.progress import SILENT, Progress

MARKER = "demo.json"
KIND = "sianms-demo"
LOCK = ".demo.lock"  # held for a whole run: two demos into one folder would interleave their stages and record


class DemoVersion(NamedTuple):
    """A dataset version a demo can synthesise: its training and validation splits and how many scene names it has."""

    train_split: str
    val_split: str
    max_scenes: int


VERSIONS = {"v1.0-mini": DemoVersion("mini_train", "mini_val", 10), "v1.0-trainval": DemoVersion("train", "val", 850)}
FOLDERS = {"synth": "data", "prepare-train": "cache-train", "prepare-val": "cache-val", "siamese": "siamese",
           "fpointnet": "fpointnet", "eval": "eval", "report": "eval/report"}
STAGES = tuple(FOLDERS)
REPLACING = "replacing"  # demo.json's list of the stages whose folders an --overwrite is deleting
STAGE_FIELDS = {  # the resolved config's fields each stage's output depends on, besides the stages before it
    "synth": ("seed", "version", "scenes", "image_scale", "scene_seconds"), "prepare-train": (), "prepare-val": (),
    "siamese": ("siamese_epochs", "siamese_lr", "precision"),
    "fpointnet": ("fpointnet", "fpointnet_epochs", "fpointnet_batch_size", "num_points", "num_object_points",
                  "precision"),
    "eval": ("nms_sweep",), "report": (),
}
ZOO_FPOINTNET = "zoo:fpointnet-single"
"""The detector a demo evaluates unless it trains its own (docs/model_zoo.md)."""
TRAINED = "trained"  # the resolved config's ``fpointnet`` when the demo trains it


@dataclass(frozen=True)
class DemoSettings:
    """Everything a demo's numbers depend on besides the seed (recorded in ``demo.json``)."""

    scenes: int  # of the version's; v1.0-mini's first two hold one mini_train and one mini_val scene
    image_scale: float  # of nuScenes' 1600 x 900 images
    scene_seconds: float  # nuScenes scenes last 20 s (40 key frames)
    siamese_epochs: int
    siamese_lr: float  # 1e-3: the paper's 1e-4 needs its 25 epochs (docs/results/reidentification.md)
    fpointnet_epochs: int
    fpointnet_batch_size: int  # the original's 32; 8 gives a small training set more steps
    num_points: int  # per frustum; the original samples 1,024
    num_object_points: int  # after masking; the original keeps 512
    nms_sweep: str  # IoU thresholds every NMS family is also evaluated at (its best is marked)

    @property
    def min_box_height(self) -> float:
        """The original's 25-px minimum 2-D box height, in pixels of these smaller images."""
        return 25.0 * self.image_scale


DEFAULT = DemoSettings(scenes=10, image_scale=0.25, scene_seconds=20.0, siamese_epochs=12, siamese_lr=1e-3,
                       fpointnet_epochs=6, fpointnet_batch_size=32, num_points=256, num_object_points=128,
                       nms_sweep="0.05,0.1,0.2,0.5")
QUICK = replace(DEFAULT, scenes=2, siamese_epochs=4, fpointnet_epochs=4, fpointnet_batch_size=8, num_points=128,
                num_object_points=64)
PROFILES = {"default": DEFAULT, "quick": QUICK}
PROFILE_SEEDS = {"default": 0, "quick": 1}
"""Each profile's seed unless one is given. The quick profile's two scenes leave one for
validation, and seed 0's holds one car within 50 m (the ego waits in a queue all 20 s): every
car AP would be 0. Seed 1's holds 235 cars, 16 in the overlap."""
DEMO_PRECISIONS = ("fp32", "bf16")  # the demo trains on the CPU, where float16 is slow (training.precision)


@dataclass(frozen=True)
class DemoConfig:
    """What `sianms demo` runs: a profile, the seed, and any of the profile's sizes overridden."""

    quick: bool = False
    seed: int | None = None  # as asked; None: the profile's (run_seed)
    version: str = "v1.0-mini"
    scenes: int | None = None
    siamese_epochs: int | None = None
    fpointnet_epochs: int | None = None
    precision: str = "fp32"
    train_fpointnet: bool = False  # train Frustum PointNets as a stage instead of evaluating the zoo's

    def __post_init__(self) -> None:
        check_seed(self.run_seed)
        if self.precision not in DEMO_PRECISIONS:
            raise SianmsError(f"--precision must be {' or '.join(DEMO_PRECISIONS)} (the demo trains on the CPU), "
                              f"got '{self.precision}'")
        if self.version not in VERSIONS:
            raise SianmsError(f"--version must be one of {', '.join(VERSIONS)}, got {self.version}")
        most = VERSIONS[self.version].max_scenes
        if self.scenes is not None and not 2 <= self.scenes <= most:
            raise SianmsError(f"--scenes must be between 2 (one training and one validation scene) and {most} "
                              f"({self.version}), got {self.scenes}")
        for name in ("siamese_epochs", "fpointnet_epochs"):
            if getattr(self, name) is not None:
                check_epochs(getattr(self, name), f"--{name.replace('_', '-')}")
        if self.fpointnet_epochs is not None and not self.train_fpointnet:
            raise SianmsError("--fpointnet-epochs needs --train-fpointnet: without it the demo evaluates the zoo's "
                              f"Frustum PointNets ({ZOO_FPOINTNET}) and trains none")

    @property
    def profile(self) -> str:
        return "quick" if self.quick else "default"

    @property
    def run_seed(self) -> int:
        """The seed every stage runs with: the one asked for, or the profile's (PROFILE_SEEDS)."""
        return PROFILE_SEEDS[self.profile] if self.seed is None else self.seed

    @property
    def splits(self) -> tuple[str, str]:
        """The (training, validation) split names of the version."""
        version = VERSIONS[self.version]
        return version.train_split, version.val_split

    @property
    def settings(self) -> DemoSettings:
        overrides = {name: getattr(self, name) for name in ("scenes", "siamese_epochs", "fpointnet_epochs")
                     if getattr(self, name) is not None}
        return replace(PROFILES[self.profile], **overrides)

    @property
    def fpointnet(self) -> str:
        """What eval's ``--fpointnet`` is: the demo's own training, or the zoo entry."""
        return TRAINED if self.train_fpointnet else ZOO_FPOINTNET

    @property
    def stages(self) -> tuple[str, ...]:
        """The stages this demo runs: every one, but the F-PointNets training when the zoo's detector is used."""
        return STAGES if self.train_fpointnet else tuple(stage for stage in STAGES if stage != "fpointnet")

    def resolved(self) -> dict[str, Any]:
        return {"profile": self.profile, "seed": self.run_seed, "version": self.version, **asdict(self.settings),
                "precision": self.precision, "fpointnet": self.fpointnet}


@dataclass
class DemoResult:
    out: Path
    manifest: dict[str, Any]
    stages_run: list[str] = field(default_factory=list)
    stages_skipped: list[str] = field(default_factory=list)
    table: dict[str, Any] | None = None


StageLog = Callable[[str, str, float | None], None]  # (stage, "start" | "done" | "skipped", seconds)


# --------------------------------------------------------------------------- the stages


def _synth(config: DemoConfig, out: Path, progress: Progress, workers: int) -> None:
    from sianms_cli.synth.generate import SynthConfig, run

    settings = config.settings
    run(SynthConfig(version=config.version, scenes=settings.scenes, image_scale=settings.image_scale,
                    scene_seconds=settings.scene_seconds, seed=config.run_seed),
        out / FOLDERS["synth"], overwrite=True, progress=progress, workers=workers)


def _prepare(stage: str) -> Callable[[DemoConfig, Path, Progress, int], None]:
    def prepare(config: DemoConfig, out: Path, progress: Progress, workers: int) -> None:
        from sianms_cli.prepare.config import PrepareConfig
        from sianms_cli.prepare.job import run

        train, val = config.splits
        run(PrepareConfig(dataroot=str(out / FOLDERS["synth"]), version=config.version,
                          split=val if stage == "prepare-val" else train, seed=config.run_seed),
            out / FOLDERS[stage], progress=progress)
    return prepare


def _siamese(config: DemoConfig, out: Path, progress: Progress, workers: int) -> None:
    from sianms_cli.training.siamese import SiameseConfig, run

    settings = config.settings
    run(SiameseConfig(cache=str(out / FOLDERS["prepare-train"]), val_cache=str(out / FOLDERS["prepare-val"]),
                      lr=settings.siamese_lr, epochs=settings.siamese_epochs, seed=config.run_seed, device="cpu",
                      precision=config.precision),
        out / FOLDERS["siamese"], resume=True, progress=progress)


def _fpointnet(config: DemoConfig, out: Path, progress: Progress, workers: int) -> None:
    from sianms_cli.training.fpointnet import FPointNetConfig, run

    settings = config.settings
    run(FPointNetConfig(cache=str(out / FOLDERS["prepare-train"]), val_cache=str(out / FOLDERS["prepare-val"]),
                        num_points=settings.num_points, num_object_points=settings.num_object_points,
                        min_box_height=settings.min_box_height, epochs=settings.fpointnet_epochs,
                        batch_size=settings.fpointnet_batch_size, seed=config.run_seed, device="cpu",
                        precision=config.precision),
        out / FOLDERS["fpointnet"], resume=True, progress=progress)


def _eval(config: DemoConfig, out: Path, progress: Progress, workers: int) -> None:
    from sianms_cli.evaluation.job import EvalConfig, run

    run(EvalConfig(dataroot=str(out / FOLDERS["synth"]), version=config.version, split=config.splits[1],
                   cache=str(out / FOLDERS["prepare-val"]), siamese=str(out / FOLDERS["siamese"]),
                   fpointnet=str(out / FOLDERS["fpointnet"]) if config.train_fpointnet else ZOO_FPOINTNET,
                   nms_sweep=config.settings.nms_sweep, seed=config.run_seed),
        out / FOLDERS["eval"], progress=progress)


def _report(config: DemoConfig, out: Path, progress: Progress, workers: int) -> None:
    from sianms_cli.reporting.report import ReportConfig, run

    run(ReportConfig(eval=str(out / FOLDERS["eval"])), out / FOLDERS["report"], overwrite=True, progress=progress)


RUNNERS = {"synth": _synth, "prepare-train": _prepare("prepare-train"),
           "prepare-val": _prepare("prepare-val"), "siamese": _siamese, "fpointnet": _fpointnet,
           "eval": _eval, "report": _report}


# --------------------------------------------------------------------------- the output folder


def claim_output(out: Path, resolved: dict[str, Any], overwrite: bool) -> dict[str, Any]:
    """The demo's record in ``out``: the one there (same config), or a fresh one.

    ``out`` may be absent or empty, or hold an earlier demo (its ``demo.json``). An earlier
    demo of another config is replaced only with ``overwrite``, and only when ``out`` holds
    nothing but the demo's own files; anything else in ``out`` is never deleted. Replacing
    keeps the stages before the first one the change affects (:data:`STAGE_FIELDS`), so more
    F-PointNets epochs retrain only F-PointNets, then evaluate and report again.
    """
    entries = _refuse_foreign_folder(out)
    marker = out / MARKER
    if marker.is_file():
        stored = read_json(marker)
        if not isinstance(stored, dict) or stored.get("kind") != KIND:
            raise OutputExistsError(f"{marker} is not a sianms demo's; choose another --out")
        check_record(stored, marker)
        if stored.get("config") == resolved:
            return _replace_stages(out, stored, stored[REPLACING]) if stored.get(REPLACING) else stored
        if not overwrite:
            differing = sorted(key for key in set(resolved) | set(stored.get("config", {}))
                               if resolved.get(key) != stored.get("config", {}).get(key))
            raise OutputExistsError(f"{out} holds a demo with another config (differs in: {', '.join(differing)}); "
                                    "pass --overwrite or choose another --out")
        foreign = [entry.name for entry in entries if entry.name not in {MARKER, *FOLDERS.values()}]
        if foreign:
            raise OutputExistsError(f"{out} is not replaced: it holds {foreign[0]}, which the demo did not write")
        kept = STAGES[:first_changed_stage(stored.get("config", {}), resolved)]
        record = {"kind": KIND, "config": resolved, "complete": False,
                  "stages": {stage: state for stage, state in stored.get("stages", {}).items() if stage in kept}}
        return _replace_stages(out, record, [stage for stage in STAGES if stage not in kept])
    make_folder(out)
    record = {"kind": KIND, "config": resolved, "complete": False, "stages": {}}
    write_json(marker, record)
    return record


def _refuse_foreign_folder(out: Path) -> list[Path]:
    """The entries of ``out`` but the lock; refuses a file, and a non-empty folder without a
    ``demo.json``. Checked before the lock is taken too, so a refused folder gets no lock file."""
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out} exists and is not a folder; choose another --out")
    entries = sorted(entry for entry in out.iterdir() if entry.name != LOCK) if out.is_dir() else []
    if entries and not (out / MARKER).is_file():
        raise OutputExistsError(f"{out} is not empty and is not a sianms demo (no {MARKER}); choose another --out")
    return entries


def _replace_stages(out: Path, record: dict[str, Any], stages: list[str]) -> dict[str, Any]:
    """Delete the folders of ``stages`` and return ``record``, written without them. Every folder is
    checked before any is deleted (:func:`foreign_stage_entry`), and the record names the stages
    being replaced while they are (:data:`REPLACING`), so a run killed meanwhile leaves a demo that
    neither says they are done nor keeps their old outputs: its rerun finishes the deletion."""
    present = [stage for stage in stages if os.path.lexists(out / FOLDERS[stage])]
    for stage in present:
        foreign = foreign_stage_entry(stage, out / FOLDERS[stage])
        if foreign is not None:
            raise OutputExistsError(f"{out} is not replaced: it holds {foreign.relative_to(out)}, which the "
                                    "demo did not write; remove it yourself or choose another --out")
    if present:
        write_json(out / MARKER, {**record, REPLACING: present})
        for stage in present:
            if (out / FOLDERS[stage]).is_dir():  # the report's folder went with the evaluation's
                shutil.rmtree(out / FOLDERS[stage])
    record = {key: value for key, value in record.items() if key != REPLACING}
    write_json(out / MARKER, record)
    return record


def foreign_stage_entry(stage: str, folder: Path) -> Path | None:
    """The first path in a stage's folder that the stage's command does not write (each command's
    own rule, as its --overwrite applies it), or None: the demo deletes a stage's folder whole."""
    if folder.is_symlink() or not folder.is_dir():
        return folder
    if not any(folder.iterdir()):
        return None
    if stage == "synth":
        from sianms_cli.synth.generate import foreign_dataset_entry
        return foreign_dataset_entry(folder)
    if stage.startswith("prepare"):
        from sianms_cli.prepare.job import foreign_cache_entry
        return foreign_cache_entry(folder)
    if stage in ("siamese", "fpointnet"):
        from sianms_cli.training.run import foreign_run_entry
        return foreign_run_entry(folder)
    if stage == "eval":
        from sianms_cli.evaluation.job import foreign_eval_entry
        return foreign_eval_entry(folder)
    from sianms_cli.reporting.report import foreign_entry, is_report_folder
    return foreign_entry(folder) if is_report_folder(folder) else folder


def check_record(record: dict[str, Any], marker: Path) -> None:
    """A demo.json read back holds a config object and, per stage, whether it is done and its
    finite wall time: what a rerun trusts to skip a stage and to share out the time."""
    for name in ("config", "stages"):
        if not isinstance(record.get(name), dict):
            raise DataFormatError(marker, f"must be an object, got {type(record.get(name)).__name__}", field=name)
    replacing = record.get(REPLACING, [])
    if not (isinstance(replacing, list) and all(stage in STAGES for stage in replacing)):
        raise DataFormatError(marker, f"must be a list of stages ({', '.join(STAGES)})", field=REPLACING)
    for stage, state in record["stages"].items():
        seconds = state.get("seconds") if isinstance(state, dict) else None
        if not isinstance(state, dict) or not isinstance(state.get("done"), bool):
            raise DataFormatError(marker, "must be an object with a true or false 'done'", field=f"stages.{stage}")
        if not (is_finite_number(seconds) and seconds >= 0):
            raise DataFormatError(marker, f"must be a number of seconds >= 0, got {seconds!r}",
                                  field=f"stages.{stage}.seconds")


def first_changed_stage(before: dict[str, Any], after: dict[str, Any]) -> int:
    """The position in :data:`STAGES` of the first stage whose fields differ between two resolved configs."""
    for position, stage in enumerate(STAGES):
        if any(before.get(name) != after.get(name) for name in STAGE_FIELDS[stage]):
            return position
    return len(STAGES)


def _is_done(record: dict[str, Any], out: Path, stage: str) -> bool:
    return bool(record["stages"].get(stage, {}).get("done")) and (out / FOLDERS[stage]).is_dir()


# --------------------------------------------------------------------------- entry point


def run(config: DemoConfig, out: str | Path, *, overwrite: bool = False, progress: Progress = SILENT,
        on_stage: StageLog | None = None, workers: int = 2) -> DemoResult:
    """Run every stage not yet done into ``out`` (module docstring) and return the comparison.

    Args:
        config: the profile, seed and overrides.
        out: the demo folder.
        overwrite: replace a demo of another config at ``out``.
        progress: each stage's own progress (it restarts per stage).
        on_stage: told when a stage starts, ends (with its wall time) or is skipped.
        workers: processes for `synth` (its output does not depend on it).
    """
    check_workers(workers)
    if config.precision == "bf16":  # before any stage: an emulated bfloat16 is refused, not met after synth
        import torch

        from sianms_cli.training.precision import resolve_precision
        resolve_precision(config.precision, torch.device("cpu"))
    log = on_stage or (lambda stage, event, seconds: None)
    out = Path(out)
    _refuse_foreign_folder(out)
    with exclusive_lock(out / LOCK, what=str(out)):
        return _run_stages(config, out, claim_output(out, config.resolved(), overwrite), log, progress, workers)


def _run_stages(config: DemoConfig, out: Path, record: dict[str, Any], log: StageLog, progress: Progress,
                workers: int) -> DemoResult:
    result = DemoResult(out, record)
    for stage in config.stages:
        if _is_done(record, out, stage):
            result.stages_skipped.append(stage)
            log(stage, "skipped", record["stages"][stage].get("seconds"))
            continue
        log(stage, "start", None)
        started = time.perf_counter()
        RUNNERS[stage](config, out, progress, workers)
        seconds = time.perf_counter() - started
        record["stages"][stage] = {"done": True, "seconds": seconds}
        write_json(out / MARKER, record)
        result.stages_run.append(stage)
        log(stage, "done", seconds)
    result.table = read_json(out / FOLDERS["eval"] / "table.json")
    record["complete"] = True
    write_json(out / MARKER, record)
    return result


def stage_shares(record: dict[str, Any]) -> dict[str, float]:
    """Each stage's share of the demo's total wall time (stages timed in this or earlier runs)."""
    seconds = {stage: float(record["stages"][stage].get("seconds") or 0.0) for stage in STAGES
               if stage in record["stages"]}
    total = sum(seconds.values())
    return {stage: (value / total if total else 0.0) for stage, value in seconds.items()}
