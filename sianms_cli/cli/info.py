"""`sianms info`: what a nuScenes-format dataroot holds."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

from sianms_cli.cli._app import ProgressBar, command


@command("info")
def info_cli(
    dataroot: Path = typer.Option(..., help="nuScenes-format dataroot."),
    version: str = typer.Option("v1.0-mini", help="Version folder inside the dataroot."),
    max_sweeps: int = typer.Option(200, help="LiDAR key-frame files read for the points-per-sweep figure (0: none)."),
    out: Optional[Path] = typer.Option(None, help="Also write the figures as JSON here (atomically)."),
    contact_sheet: Optional[Path] = typer.Option(
        None, "--contact-sheet", help="Also draw the six cameras of one day, one night and one rain key frame "
        "into this .png or .jpg (rows the dataset lacks are left out)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing --out or --contact-sheet file."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    as_json: bool = typer.Option(False, "--json", help="Print the figures as JSON."),
) -> None:
    """Describe a nuScenes-format dataset and hold each figure against real nuScenes.

    Scenes (and how many are at night, in rain, and both, read from the words "night" and
    "rain" in their descriptions, as on real nuScenes), samples, annotations per category,
    objects per keyframe (by class), LiDAR points per annotation and per sweep, visibility and
    attribute shares; how often one object is imaged twice: image boxes per 3-D box (the devkit's
    2-D export rule) and the share imaged by >= 2 cameras by class and by distance, the cars'
    camera-overlap share, their azimuth and heading-to-axis histograms; and how much of the ego's
    driving goes straight. Each figure prints beside its nuScenes value and source.
    """
    from sianms_cli.reporting.dataset_summary import InfoConfig, format_summary, run

    config = InfoConfig(dataroot=str(dataroot), version=version, max_sweeps=max_sweeps)
    with ProgressBar(quiet) as bar:
        summary = run(config, out, contact_sheet=contact_sheet, overwrite=overwrite, progress=bar)
    if as_json:
        typer.echo(json.dumps(summary, indent=2))
        return
    typer.echo(format_summary(summary))
    if contact_sheet is not None:
        drawn = ", ".join(f"{row['condition']} {row['scene']}" for row in summary["contact_sheet"]["rows"])
        typer.echo(f"contact sheet: {contact_sheet} ({drawn})")
