"""`sianms info`: what a nuScenes-format dataroot holds."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from sianms_cli.cli._app import command
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.reporting.dataset_summary import format_summary, summarize


@command("info")
def info_cli(
    dataroot: Path = typer.Argument(..., help="nuScenes-format dataroot."),
    version: str = typer.Option("v1.0-mini", help="Version folder inside the dataroot."),
    max_sweeps: int = typer.Option(200, help="LiDAR keyframe files read for the points-per-sweep figure (0: none)."),
    as_json: bool = typer.Option(False, "--json", help="Print the figures as JSON."),
) -> None:
    """Describe a nuScenes-format dataset: counts, class mix, LiDAR points, overlap share.

    Scenes, samples, annotations per category, objects per keyframe, LiDAR points per
    annotation and per sweep, visibility and attribute shares, and the share of car
    annotations in the camera-overlap region.
    """
    summary = summarize(NuScenesDB(dataroot, version), max_sweeps=max_sweeps)
    typer.echo(json.dumps(summary, indent=2) if as_json else format_summary(summary))
