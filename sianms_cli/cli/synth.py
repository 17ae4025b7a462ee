"""`sianms synth`: write a synthetic dataset in the nuScenes on-disk format.

The library is imported inside the command, so ``sianms --help`` loads no numpy-heavy code.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Optional

import typer

from sianms_cli.cli._app import ProgressBar, command


@command("synth")
def synth_cli(
    out: Path = typer.Option(..., help="Dataroot to write: absent, empty, or an earlier synth output (--overwrite)."),
    version: str = typer.Option("v1.0-mini", help="Version folder; v1.0-mini and v1.0-trainval use the devkit's "
                                                  "scene names."),
    scenes: Optional[int] = typer.Option(None, help="Number of 20 s scenes (default: 10 for v1.0-mini)."),
    image_scale: float = typer.Option(0.5, help="Camera images are 1600x900 times this scale."),
    seed: int = typer.Option(0, help="Same seed, byte-identical dataset."),
    sensors: str = typer.Option("all", help="'all' writes JPEGs and .pcd.bin sweeps; 'none' the tables only "
                                            "(the same annotations)."),
    scene_seconds: float = typer.Option(20.0, help="Scene length, up to 20 s; a shorter scene is the start of the "
                                                   "full one."),
    workers: int = typer.Option(1, help="Processes sensing scenes in parallel (the output does not depend on it)."),
    overwrite: bool = typer.Option(False, "--overwrite",
                                   help="Replace --out if it holds an earlier synth output and nothing else."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    as_json: bool = typer.Option(False, "--json", help="Print the result as JSON (and nothing else) on stdout."),
) -> None:
    """Write a realistic synthetic nuScenes-format dataset (six cameras, a 32-beam LiDAR, 2 Hz keyframes)."""
    from sianms_cli.synth.generate import SynthConfig, run

    config = SynthConfig(version=version, scenes=scenes, image_scale=image_scale, seed=seed, sensors=sensors,
                         scene_seconds=scene_seconds)
    with ProgressBar(quiet) as bar:
        result = run(config, out, overwrite=overwrite, progress=bar, workers=workers)
    if as_json:
        typer.echo(json.dumps({**dataclasses.asdict(result), "out": str(result.out)}, indent=2))
        return
    typer.echo(f"wrote {result.scenes} scenes ({result.samples} samples) to {result.out / result.version}")
