"""`sianms metrics`: the nuScenes detection metrics of a results file, per region."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from sianms_cli.cli._app import ProgressBar, command


@command("metrics")
def metrics_cli(
    dataroot: Path = typer.Option(..., help="nuScenes-format dataroot."),
    version: str = typer.Option("v1.0-mini", help="Version folder inside the dataroot."),
    split: str = typer.Option(..., help="Split: predefined (val, mini_val, ...) or a name from <version>/splits.json."),
    results: Path = typer.Option(..., help="Results JSON in the nuScenes submission format (global frame)."),
    config: str = typer.Option("detection_cvpr_2019", help="'detection_cvpr_2019', 'paper' (car, pedestrian, bicycle) "
                               "or a JSON file with the devkit's config fields."),
    region: str = typer.Option("all", help="Comma-separated regions: all, overlap, non-overlap, "
                               "'overlap:CAM_A|CAM_B' (one camera pair), 'overlap:*' (every pair)."),
    out: Optional[Path] = typer.Option(None, help="Write the full report as JSON here (atomically)."),
    details: Optional[Path] = typer.Option(None, help="Write the 101-point curves here (atomically): per region, "
                                                      "the devkit's metrics_details.json."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing --out or --details file."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    as_json: bool = typer.Option(False, "--json",
                                 help="Print the report as JSON instead of the table; nothing else goes to stdout."),
) -> None:
    """nuScenes detection metrics of a results file, as the official devkit computes them.

    AP per class at each distance threshold, ATE/ASE/AOE/AVE/AAE, mAP and NDS, over all boxes or a region.

    As in the devkit, a class without ground truth scores AP 0 and stays in mAP and NDS; the table marks it *.
    """
    from sianms_cli.metrics.evaluate import MetricsConfig, run
    from sianms_cli.metrics.report import report_json
    from sianms_cli.reporting.metrics_table import format_metrics

    metrics_config = MetricsConfig(dataroot=str(dataroot), version=version, split=split, results=str(results),
                                   detection_config=config, regions=tuple(region.split(",")))
    with ProgressBar(quiet) as bar:
        report = run(metrics_config, out, details=details, overwrite=overwrite, progress=bar)
    if as_json:
        typer.echo(report_json(report))
    else:
        typer.echo(format_metrics(report))
    for written in (out, details):
        if written is not None:
            typer.echo(f"wrote {written}", err=as_json)
