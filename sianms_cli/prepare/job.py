"""`sianms prepare`: the paper's offline step (§III-A, §IV-B) as a streaming, sharded, resumable job.

For every key frame of a split and every camera: 2D detections (simulated or from a file),
their association with the projected ground truth (+ the projected ground truth of missed
objects on training splits), ROI features from a backbone's stride-16 map, and the LiDAR
frustum of each detection; then the pairs of detections of one instance in two contiguous
cameras. Written under ``out`` as three Parquet datasets, one file per scene (the shard),
and a manifest (see :mod:`sianms_cli.data.cache`).

This module sits above ``detection2d/`` and ``data/`` and below ``cli/``: it is the
orchestration only. It lives at the package top rather than in ``pipelines/``, which DESIGN.md
gives to evaluation-time duplicate handling.

Determinism: every random draw comes from a generator seeded with (seed, sample_data token),
so the bytes written depend neither on ``workers`` nor on ``shard``, nor on whether the run
was interrupted and resumed.
"""

from __future__ import annotations

import multiprocessing
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import torch

from sianms_cli.data.cache import (
    MANIFEST, SHARDS, ShardWriter, clear_shard, read_manifest, shard_done, write_manifest,
)
from sianms_cli.data.schemas import DATASETS
from sianms_cli.errors import OutputExistsError, SianmsError
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.rigs import sample_rigs
from sianms_cli.nuscenes.splits import split_scene_names
from sianms_cli.prepare.config import PrepareConfig
from sianms_cli.prepare.sample import Preparer


@dataclass
class PrepareResult:
    out: Path
    manifest: dict[str, Any]
    shards_run: list[str] = field(default_factory=list)
    shards_skipped: list[str] = field(default_factory=list)


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
    return chosen


# ------------------------------------------------------------------------------ one shard


def write_scene_shard(preparer: Preparer, out: Path, scene_token: str, shard: str,
                      on_sample: Callable[[], None] | None = None) -> dict:
    """Write one scene's shard; return its completion record."""
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
    torch.set_num_threads(1)
    _WORKER = Preparer(config)


def _run_in_worker(args: tuple[str, str, str]) -> tuple[str, int]:
    out, scene_token, shard = args
    assert _WORKER is not None
    record = write_scene_shard(_WORKER, Path(out), scene_token, shard)
    return shard, record["samples"]


# ------------------------------------------------------------------------------ entry point


def prepare(
    config: PrepareConfig,
    out: str | Path,
    workers: int = 1,
    shard: str | None = None,
    overwrite: bool = False,
    progress: bool = True,
) -> PrepareResult:
    """Prepare the cache for ``config`` under ``out`` (see the module docstring).

    A cache that holds finished shards of the same resolved config is resumed: finished shards
    are skipped, unfinished ones rewritten. A cache made with another config is refused unless
    ``overwrite``; so is a non-empty folder that is not a cache.

    Args:
        config: what to compute.
        out: cache folder.
        workers: processes (the output does not depend on it).
        shard: "K/N": this run does the scenes whose position in the split is K mod N.
        overwrite: delete an existing cache first.
        progress: show a tqdm bar over samples.
    """
    k, n = parse_shard(shard)
    if workers < 1:
        raise SianmsError(f"--workers must be at least 1, got {workers}")
    out = Path(out)
    resolved = config.resolved()
    db = NuScenesDB(config.dataroot, config.version)
    scenes = split_scenes(db, config.split)
    preparer = Preparer(config, db)  # validates detector file and weights before anything is written
    _claim_output(out, resolved, overwrite)
    expected = [name for _, name in scenes]
    mine = [(token, name) for i, (token, name) in enumerate(scenes) if i % n == k]
    todo = [(token, name) for token, name in mine if not shard_done(out, name)]
    skipped = [name for token, name in mine if shard_done(out, name)]
    total = sum(len(db.sample_tokens_of_scene(token)) for token, _ in todo)
    from tqdm import tqdm

    with tqdm(total=total, unit="sample", disable=not progress, desc="prepare") as bar:
        if workers == 1 or len(todo) <= 1:
            for token, name in todo:
                write_scene_shard(preparer, out, token, name, on_sample=lambda: bar.update(1))
        else:
            del preparer
            context = multiprocessing.get_context("spawn")
            with context.Pool(min(workers, len(todo)), initializer=_init_worker, initargs=(config,)) as pool:
                for _, samples in pool.imap_unordered(_run_in_worker, [(str(out), t, s) for t, s in todo]):
                    bar.update(samples)
    manifest = write_manifest(out, resolved, expected)
    return PrepareResult(out, manifest, [name for _, name in todo], skipped)


def _claim_output(out: Path, resolved: dict[str, Any], overwrite: bool) -> None:
    """Create ``out`` or check it is this config's cache; write the manifest with the config."""
    manifest = read_manifest(out) if out.is_dir() else None
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out} exists and is not a folder")
    if overwrite and out.is_dir():
        if manifest is None and any(out.iterdir()):
            raise OutputExistsError(f"{out} is not a sianms cache (no {MANIFEST}); refusing to delete it")
        for name in (*DATASETS, SHARDS):
            shutil.rmtree(out / name, ignore_errors=True)
        (out / MANIFEST).unlink(missing_ok=True)
        manifest = None
    if manifest is not None:
        if manifest.get("config") != resolved:
            differing = sorted(key for key in set(resolved) | set(manifest.get("config", {}))
                               if resolved.get(key) != manifest.get("config", {}).get(key))
            raise OutputExistsError(
                f"{out} holds a cache prepared with another config (differs in: {', '.join(differing)}); "
                "pass --overwrite or choose another --out")
        return
    if out.is_dir() and any(out.iterdir()):
        raise OutputExistsError(f"{out} exists and is not empty; pass --overwrite or choose another --out")
    out.mkdir(parents=True, exist_ok=True)
    write_manifest(out, resolved, [])
