"""`sianms metrics`: the nuScenes detection metrics of a results file, per region."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from sianms_cli.cli._app import command
from sianms_cli.evaluation.evaluate import format_report, report_json, run_metrics


@command("metrics")
def metrics_cli(
    dataroot: Path = typer.Option(..., help="nuScenes-format dataroot."),
    results: Path = typer.Option(..., help="Results JSON in the nuScenes submission format (global frame)."),
    split: str = typer.Option(..., help="Split: predefined (val, mini_val, ...) or a name from <version>/splits.json."),
    version: str = typer.Option("v1.0-mini", help="Version folder inside the dataroot."),
    config: str = typer.Option("detection_cvpr_2019", help="'detection_cvpr_2019', 'paper' (car, pedestrian, bicycle) "
                               "or a JSON file with the devkit's config fields."),
    region: str = typer.Option("all", help="Comma-separated regions: all, overlap, non-overlap, "
                               "'overlap:CAM_A|CAM_B' (one camera pair), 'overlap:*' (every pair)."),
    out: Optional[Path] = typer.Option(None, help="Write the full report as JSON here (atomically)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing --out file."),
    as_json: bool = typer.Option(False, "--json", help="Print the report as JSON instead of the table."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """nuScenes detection metrics of a results file, as the official devkit computes them.

    AP per class at each distance threshold, ATE/ASE/AOE/AVE/AAE, mAP and NDS, for all boxes
    or only those in a camera-overlap region.
    """
    regions = [name for name in region.split(",") if name.strip()]
    bar = None
    if not quiet and results.is_file():
        from tqdm import tqdm

        bar = tqdm(total=results.stat().st_size, unit="B", unit_scale=True, desc="reading results",
                   leave=False)
    try:
        report = run_metrics(dataroot, version, split, results, config, regions, out, overwrite,
                             progress=bar.update if bar is not None else None)
    finally:
        if bar is not None:
            bar.close()
    typer.echo(report_json(report) if as_json else format_report(report))
    if out is not None and not as_json:
        typer.echo(f"wrote {out}")
