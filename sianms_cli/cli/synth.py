"""`sianms synth`: write a synthetic dataset in the nuScenes on-disk format."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from sianms_cli.cli._app import command
from sianms_cli.synth.generate import SynthConfig, synthesize


@command("synth")
def synth_cli(
    out: Path = typer.Argument(..., help="Dataroot to create (must be empty or absent)."),
    version: str = typer.Option("v1.0-mini", help="Version folder; v1.0-mini and v1.0-trainval use the devkit's scene names."),
    scenes: Optional[int] = typer.Option(None, help="Number of 20 s scenes (default: 10 for v1.0-mini)."),
    image_scale: float = typer.Option(0.5, help="Camera images are 1600x900 times this scale."),
    seed: int = typer.Option(0, help="Same seed, byte-identical dataset."),
    sensors: str = typer.Option("all", help="'all' writes JPEGs and .pcd.bin sweeps; 'none' the tables only."),
    scene_seconds: float = typer.Option(20.0, help="Scene length, up to 20 s; a shorter scene is the start of the full one."),
    workers: int = typer.Option(1, help="Processes sensing scenes in parallel (the output does not depend on it)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a non-empty OUT."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Write a realistic synthetic nuScenes-format dataset (six cameras, a 32-beam LiDAR, 2 Hz keyframes)."""
    config = SynthConfig(version=version, scenes=scenes, image_scale=image_scale, seed=seed, sensors=sensors,
                         scene_seconds=scene_seconds)
    root = synthesize(out, config, overwrite=overwrite, progress=not quiet, workers=workers)
    typer.echo(f"wrote {len(config.scene_names())} scenes to {root}/{version}")
