"""`sianms prepare`: the paper's offline step (§III-A, §IV-B) as a streaming, sharded, resumable job.

For every key frame of a split and every camera: 2D detections (simulated or from a file),
their association with the projected ground truth (+ the projected ground truth of missed
objects on training splits), ROI features from a backbone's stride-16 map, and the LiDAR
frustum of each detection; then the pairs of detections of one instance in two contiguous
cameras. Written under ``out`` as three Parquet datasets, one file per scene (the shard),
and a manifest (see :mod:`sianms_cli.data.cache`).

This module is the orchestration only: which shards to write, in which process, under which
lock, and the manifest; :mod:`.sample` computes one key frame.

Determinism: every random draw comes from a generator seeded with (seed, sample_data token),
so the bytes written depend neither on ``workers`` nor on ``shard``, nor on whether the run
was interrupted and resumed.
"""

from __future__ import annotations

import re
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Generator

import numpy as np

from sianms_cli.data.cache import (
    FOLDER_LOCK, MANIFEST, SHARDS, ShardWriter, clear_shard, read_manifest, shard_done, shard_lock_path,
    write_manifest,
)
from sianms_cli.data.schemas import DATASETS
from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError, check_workers
from sianms_cli.io import (PARTIAL_SUFFIX, FolderBusyError, exclusive_lock, first_foreign_file, partial_of,
                          release_lock, try_lock)
from sianms_cli.nuscenes.fingerprint import dataset_fingerprint
from sianms_cli.nuscenes.tables import CAMERA_CHANNELS
from sianms_cli.processes import TASK_TORCH_THREADS, task_torch_threads, worker_pool
from sianms_cli.progress import SILENT, Progress
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.sample_rigs import sample_rigs
from sianms_cli.nuscenes.splits import split_scene_names
from sianms_cli.prepare.config import PrepareConfig
from sianms_cli.prepare.sample import Preparer


@dataclass
class PrepareResult:
    """What one run did: the shards it wrote, found finished, or left to another run."""

    out: Path
    manifest: dict[str, Any]
    shards_run: list[str] = field(default_factory=list)
    shards_skipped: list[str] = field(default_factory=list)
    shards_busy: list[str] = field(default_factory=list)


def parse_shard(text: str | None) -> tuple[int, int]:
    """'K/N' -> (K, N) with 0 <= K < N; None -> (0, 1)."""
    if text is None:
        return 0, 1
    try:
        k, n = (int(part) for part in text.split("/"))
    except ValueError:
        raise SianmsError(f"--shard must look like K/N (e.g. 0/4), got '{text}'") from None
    if not (n >= 1 and 0 <= k < n):
        raise SianmsError(f"--shard K/N needs 0 <= K < N, got '{text}'")
    return k, n


def split_scenes(db: NuScenesDB, split: str) -> list[tuple[str, str]]:
    """(scene token, shard name) of the split's scenes, in scene-table order.

    The shard name is the scene name, or the scene token when names repeat.
    """
    names = set(split_scene_names(split, db.version, db.dataroot))
    scenes = db.table("scene")
    all_names = scenes.column("name").tolist()
    unique = len(set(all_names)) == len(all_names)
    chosen = [(tok, name if unique else tok) for tok, name in zip(scenes.tokens.tolist(), all_names) if name in names]
    if not chosen:
        raise SianmsError(f"split '{split}' has no scene in {db.table_root}")
    for token, shard in chosen:
        if not SHARD_NAME.fullmatch(shard):
            raise DataFormatError(db.table_root / "scene.json", f"'{shard}' cannot name the scene's files (letters, "
                                  "digits, '.', '_' and '-', starting with a letter or digit)", token=token,
                                  field="name" if unique else "token")
    return chosen


SHARD_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,199}")
"""A scene's name (or token) names its files in a cache and an evaluation: one plain path component,
so '../x' cannot write or delete outside the folder and '*' cannot match other scenes' files."""


# ------------------------------------------------------------------------------ inputs


def check_inputs(db: NuScenesDB, config: PrepareConfig, scenes: list[tuple[str, str]]) -> None:
    """Refuse, before anything is written, a dataset the run would fail on part-way.

    Each scene's samples must form its chain, every camera key frame an image size and a
    calibration with an intrinsic matrix; every key-frame camera image and LiDAR sweep of the
    scenes must exist (a dataset written with ``synth --sensors none`` has tables only), and
    ``--sweeps`` needs LiDAR sweeps between key frames: without them the previous *key
    frames*, 0.5 s apart, would be stacked as if they were 0.05 s sweeps.
    """
    sample_rigs(db, [sample for token, _ in scenes for sample in db.sample_tokens_of_scene(token)])
    sample_data = db.table("sample_data")
    key = sample_data.column("is_key_frame")
    channels = db.sample_data_channels()
    wanted = np.isin(channels, ("LIDAR_TOP", *CAMERA_CHANNELS))
    scene_of_sample = db.table("sample").rows("scene_token")
    chosen_scenes = db.table("scene").indices([token for token, _ in scenes])
    rows = np.flatnonzero(key & wanted & np.isin(scene_of_sample[sample_data.rows("sample_token")], chosen_scenes))
    filenames = sample_data.column("filename")
    for row in rows.tolist():
        path = db.dataroot / str(filenames[row])
        if not path.is_file():
            raise DataFormatError(
                path, "sensor file not found (a dataset written with `sianms synth --sensors none` has "
                "tables only; prepare needs its images and LiDAR)", token=str(sample_data.tokens[row]),
                field="filename")
    if config.sweeps > 0 and not np.any(~key & (channels == "LIDAR_TOP")):
        raise SianmsError(
            f"--sweeps {config.sweeps}: {db.table_root} has no LiDAR sweeps between key frames "
            "(sample_data records of LIDAR_TOP with is_key_frame false); use --sweeps 0")


# ------------------------------------------------------------------------------ the cache folder


def refuse_foreign_folder(out: Path) -> None:
    """Refuse, without touching it, a folder that holds anything but a sianms cache.

    Another run starting into the same new folder holds the folder lock and writes its
    manifest (through a temporary file) while this one looks: neither is foreign content, and
    the entries are listed before the manifest is read, so a manifest renamed into place in
    between is seen.
    """
    if not out.is_dir():
        return
    entries = [e for e in out.iterdir() if e.name != FOLDER_LOCK and not e.name.endswith(PARTIAL_SUFFIX)]
    if entries and read_manifest(out) is None:
        raise OutputExistsError(
            f"{out} is not empty and is not a sianms cache (no {MANIFEST}); choose another --out")


def claim_output(out: Path, resolved: dict[str, Any], expected: list[str], dataroot: Path, overwrite: bool) -> None:
    """Make ``out`` this config's cache, or check that it is; write its manifest.

    Runs under the folder lock, so two runs starting together agree on what ``out`` holds.
    An empty or absent folder becomes a new cache. A cache of the same config is resumed.
    A cache of another config is refused unless ``overwrite``, and ``overwrite`` deletes only
    a folder recognisable as a sianms cache (its manifest), and only while no other run is
    writing one of its shards. Anything else is refused: a command deletes only its own.
    """
    manifest = read_manifest(out)
    entries = [entry.name for entry in out.iterdir()
               if entry.name != FOLDER_LOCK and partial_of(entry.name) != MANIFEST]
    if manifest is None and entries:
        raise OutputExistsError(
            f"{out} is not empty and is not a sianms cache (no {MANIFEST}); choose another --out")
    if manifest is not None and manifest["config"] != resolved:
        if not overwrite:
            stored = manifest["config"]
            differing = sorted(key for key in set(resolved) | set(stored) if resolved.get(key) != stored.get(key))
            raise OutputExistsError(
                f"{out} holds a cache prepared with another config (differs in: {', '.join(differing)}); "
                "pass --overwrite to replace it or choose another --out")
    if manifest is not None and overwrite:
        shards = manifest["config"].get("split_scenes")
        _delete_cache_content(out, shards if isinstance(shards, list) else [])
    write_manifest(out, resolved, expected, dataroot)


def _shard_files(shards: list[Any]) -> dict[str, set[str]]:
    """The files of a cache's shards (``shards``: its split's scenes), by subfolder."""
    names = [str(shard) for shard in shards]
    own = {name: {f"{shard}.parquet" for shard in names} for name in DATASETS}
    own[SHARDS] = {f"{shard}{suffix}" for shard in names for suffix in (".json", ".lock")}
    return own


def foreign_cache_entry(out: Path) -> Path | None:
    """The first path in a cache folder that `sianms prepare` does not write (links never are), or
    None: what deleting the folder would take of someone else's."""
    manifest = read_manifest(out)
    shards = manifest["config"].get("split_scenes") if manifest is not None else None
    own = _shard_files(shards if isinstance(shards, list) else [])

    def is_own(entry: Path, names: set[str]) -> bool:
        return (partial_of(entry.name) or entry.name) in names

    for entry in sorted(out.iterdir()):
        if entry.is_symlink() or not (entry.is_dir() or is_own(entry, {MANIFEST, FOLDER_LOCK})):
            return entry
        if entry.is_dir():
            foreign = (entry if entry.name not in own
                       else first_foreign_file(entry, lambda file: is_own(file, own[entry.name])))
            if foreign is not None:
                return foreign
    return None


def _delete_cache_content(out: Path, shards: list[str]) -> None:
    """Remove the files of a cache's shards (``shards``: its split's scenes), a killed write's
    temporaries included, and the folders they leave empty. Anything else in them is yours
    and stays. The manifest stays until the caller rewrites it, so an interrupted overwrite
    leaves a folder still recognisable as a cache."""
    held = []
    for lock_path in sorted((out / SHARDS).glob("*.lock")):
        descriptor = try_lock(lock_path)
        if descriptor is None:
            raise FolderBusyError(f"{out}: shard {lock_path.stem} is being written by another sianms process; "
                                  "wait for it before --overwrite")
        held.append(descriptor)
    try:
        for name, files in _shard_files(shards).items():
            folder = out / name
            if not folder.is_dir() or folder.is_symlink():
                continue
            for entry in folder.iterdir():
                if (partial_of(entry.name) or entry.name) in files and entry.is_file() and not entry.is_symlink():
                    entry.unlink()
            if not any(folder.iterdir()):
                folder.rmdir()
    finally:
        for descriptor in held:
            release_lock(descriptor)


def refresh_manifest(out: Path, resolved: dict[str, Any], expected: list[str], dataroot: Path) -> dict[str, Any]:
    """Rewrite the manifest from the finished shards, under the folder lock."""
    with exclusive_lock(out / FOLDER_LOCK, what=str(out), blocking=True):
        return write_manifest(out, resolved, expected, dataroot)


# ------------------------------------------------------------------------------ one shard


def write_scene_shard(preparer: Preparer, out: Path, scene_token: str, shard: str,
                      on_sample: Callable[[], None] | None = None) -> str:
    """Write one scene's shard unless it is finished or another run holds it.

    Returns "written", "finished" (found done) or "busy" (another run is writing it).
    """
    lock = try_lock(shard_lock_path(out, shard))
    if lock is None:
        return "busy"
    try:
        if shard_done(out, shard):
            return "finished"
        _write_shard(preparer, out, scene_token, shard, on_sample)
        return "written"
    finally:
        release_lock(lock)


def _write_shard(preparer: Preparer, out: Path, scene_token: str, shard: str,
                 on_sample: Callable[[], None] | None) -> dict:
    db = preparer.db
    clear_shard(out, shard)
    samples = db.sample_tokens_of_scene(scene_token)
    scene_name = str(db.table("scene").column("name")[db.table("scene").index(scene_token)])
    rigs, which = sample_rigs(db, samples)
    with ShardWriter(out, shard, preparer.schemas) as writer:
        for sample_token, rig_index in zip(samples, which.tolist()):
            if rig_index >= 0:
                for name, table in preparer.sample(scene_token, scene_name, sample_token, rigs[rig_index]).items():
                    writer.write(name, table)
            if on_sample is not None:
                on_sample()
        return writer.commit({"scene_token": scene_token, "scene_name": scene_name, "samples": len(samples)})


# ------------------------------------------------------------------------------ workers

_WORKER: Preparer | None = None


def _init_worker(config: PrepareConfig) -> None:
    global _WORKER
    import torch

    torch.set_num_threads(TASK_TORCH_THREADS)
    _WORKER = Preparer(config)


def _run_in_worker(args: tuple[str, str, str]) -> tuple[str, str]:
    out, scene_token, shard = args
    assert _WORKER is not None
    return shard, write_scene_shard(_WORKER, Path(out), scene_token, shard)


# ------------------------------------------------------------------------------ entry point


def run(
    config: PrepareConfig,
    out: str | Path,
    *,
    overwrite: bool = False,
    progress: Progress = SILENT,
    workers: int = 1,
    shard: str | None = None,
) -> PrepareResult:
    """Prepare the cache for ``config`` under ``out`` (see the module docstring).

    A cache that holds finished shards of the same resolved config is resumed: finished shards
    are skipped, unfinished ones rewritten. Runs into the same ``out`` cooperate shard by
    shard (each shard is written by the run that locks it; the others skip it), so array jobs
    with ``shard`` and plain reruns can share a cache. A cache made with another config is
    refused unless ``overwrite``; a non-empty folder that is not a cache is always refused.

    Args:
        config: what to compute.
        out: cache folder.
        overwrite: replace a cache of another config.
        progress: told the number of samples, then each one done.
        workers: processes (the output does not depend on it).
        shard: "K/N": this run does the scenes whose position in the split is K mod N.
    """
    k, n = parse_shard(shard)
    check_workers(workers)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out} exists and is not a folder; choose another --out")
    db = NuScenesDB(config.dataroot, config.version)
    scenes = split_scenes(db, config.split)
    mine = [(token, name) for i, (token, name) in enumerate(scenes) if i % n == k]
    check_inputs(db, config, mine)
    preparer = Preparer(config, db)  # validates the detector file and the weights before anything is written
    expected = [name for _, name in scenes]
    resolved = config.resolved(dataset_fingerprint(db.table_root), expected)
    refuse_foreign_folder(out)
    with exclusive_lock(out / FOLDER_LOCK, what=str(out), blocking=True):
        claim_output(out, resolved, expected, db.dataroot, overwrite)
    finished = {name for _, name in mine if shard_done(out, name)}
    todo = [(token, name) for token, name in mine if name not in finished]
    result = PrepareResult(out, {}, shards_skipped=[name for _, name in mine if name in finished])
    samples = {name: len(db.sample_tokens_of_scene(token)) for token, name in todo}
    progress.start(sum(samples.values()), "sample", "prepare")
    outcomes = {"written": result.shards_run, "finished": result.shards_skipped, "busy": result.shards_busy}
    try:
        with closing(_run_shards(preparer, config, out, todo, samples, workers, progress)) as shards:
            for name, outcome in shards:
                outcomes[outcome].append(name)
    finally:
        result.manifest = refresh_manifest(out, resolved, expected, db.dataroot)
    return result


def _run_shards(preparer: Preparer, config: PrepareConfig, out: Path, todo: list[tuple[str, str]],
                samples: dict[str, int], workers: int, progress: Progress
                ) -> Generator[tuple[str, str], None, None]:
    """(shard, outcome) of each shard to do, in this process or in ``workers`` processes;
    ``samples`` counts each shard's samples for the progress of worker-written shards."""
    if workers == 1 or len(todo) <= 1:
        with task_torch_threads():
            for token, name in todo:
                yield name, write_scene_shard(preparer, out, token, name, on_sample=progress.advance)
        return
    with worker_pool(min(workers, len(todo)), _init_worker, (config,)) as pool:
        for name, outcome in pool.imap_unordered(_run_in_worker, [(str(out), t, s) for t, s in todo]):
            progress.advance(samples[name])
            yield name, outcome
