"""`sianms prepare`: 2D detections, ROI features, LiDAR frustums and overlap pairs to Parquet."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

from sianms_cli.cli._app import ProgressBar, command
from sianms_cli.nuscenes.classes import PAPER_CLASSES


@command("prepare")
def prepare_cli(
    dataroot: Path = typer.Option(..., help="nuScenes-format dataroot."),
    version: str = typer.Option("v1.0-mini", help="Version folder inside the dataroot."),
    split: str = typer.Option(..., help="Split (mini_train, mini_val, train, val, ... or a custom one)."),
    out: Path = typer.Option(..., help="Cache folder to write (resumed if it holds the same config)."),
    detector: str = typer.Option("simulated", help="'simulated' or 'file:PATH' (.parquet/.json external detections)."),
    backbone: str = typer.Option("tiny", help="'tiny' (seeded small conv net) or 'resnet50-c4' (needs --weights)."),
    weights: Optional[Path] = typer.Option(None,
                                           help="Local torchvision detection/resnet50 checkpoint for resnet50-c4."),
    classes: str = typer.Option(",".join(PAPER_CLASSES), help="Comma-separated detection classes."),
    seed: int = typer.Option(0, help="Same seed, byte-identical cache."),
    iou_threshold: float = typer.Option(0.5, help="Minimum 2D IoU to associate a detection with the ground truth."),
    fill_missed: Optional[bool] = typer.Option(None, "--fill-missed/--no-fill-missed", show_default=False,
                                               help="Add projected GT of missed objects "
                                                    "[default: on for train splits]."),
    roi_size: int = typer.Option(7, help="ROI Align output size (PH = PW)."),
    sampling_ratio: int = typer.Option(0, help="ROI Align samples per bin side; <= 0 adaptive."),
    sweeps: int = typer.Option(0, help="Earlier LiDAR sweeps added to each key frame "
                                       "(needs sweeps between key frames)."),
    min_depth: float = typer.Option(1.0, help="Frustum near depth, metres."),
    max_depth: Optional[float] = typer.Option(None, help="Frustum far depth, metres [default: none]."),
    workers: int = typer.Option(1, help="Processes (the output does not depend on it)."),
    shard: Optional[str] = typer.Option(None, help="K/N: do only the scenes at positions K mod N (array jobs)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a cache of another config at --out."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    as_json: bool = typer.Option(False, "--json", help="Print what was done as JSON."),
) -> None:
    """Run the offline step of the paper: detections, ROI features, frustums and pairs, as Parquet.

    Runs into the same --out cooperate shard by shard (one scene per shard); an interrupted
    run leaves its finished shards, and a rerun resumes.
    """
    from sianms_cli.prepare.config import PrepareConfig
    from sianms_cli.prepare.job import run

    config = PrepareConfig(
        dataroot=str(dataroot), version=version, split=split, detector=detector, backbone=backbone,
        weights=None if weights is None else str(weights),
        classes=tuple(name.strip() for name in classes.split(",") if name.strip()), seed=seed,
        iou_threshold=iou_threshold, fill_missed=fill_missed, roi_size=roi_size, sampling_ratio=sampling_ratio,
        sweeps=sweeps, min_depth=min_depth, max_depth=max_depth,
    )
    with ProgressBar(quiet) as bar:
        result = run(config, out, overwrite=overwrite, progress=bar, workers=workers, shard=shard)
    manifest = result.manifest
    if as_json:
        typer.echo(json.dumps({"out": str(result.out), "written": result.shards_run,
                               "already_finished": result.shards_skipped, "busy": result.shards_busy,
                               "complete": manifest["complete"], "missing_shards": manifest["missing_shards"],
                               "counts": manifest["counts"]}, indent=2))
        return
    counts = manifest["counts"]
    busy = f", {len(result.shards_busy)} being written by another run" if result.shards_busy else ""
    typer.echo(
        f"prepared {len(result.shards_run)} shard(s), skipped {len(result.shards_skipped)} finished{busy}; "
        f"{manifest['shards_finished']}/{manifest['shards_expected']} shards in {result.out}: "
        f"{counts['samples']} samples, {counts['detections']} detections, {counts['frustums']} frustums, "
        f"{counts['pairs']} pairs" + ("" if manifest["complete"] else " (incomplete: other shards pending)")
    )
