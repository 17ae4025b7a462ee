"""`sianms eval`: vanilla, NMS variants, siaNMS, hybrid, gated siaNMS and the oracle, end to end to Table I."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

from sianms_cli.cli._app import ProgressBar, command


@command("eval")
def eval_cli(
    dataroot: Path = typer.Option(..., help="nuScenes-format dataroot."),
    version: str = typer.Option("v1.0-mini", help="Version folder inside the dataroot."),
    split: str = typer.Option(..., help="Split to evaluate (its `sianms prepare` cache is --cache)."),
    cache: Path = typer.Option(..., help="Complete `sianms prepare` cache of --split."),
    siamese: Path = typer.Option(..., help="`sianms train siamese` run folder (or its checkpoint.pt), or zoo:NAME."),
    fpointnet: Path = typer.Option(..., help="`sianms train fpointnet` run folder (or its checkpoint.pt), or "
                                             "zoo:NAME (`sianms zoo`)."),
    out: Path = typer.Option(..., help="Evaluation folder to write (resumed if it holds the same config)."),
    methods: str = typer.Option("all", help="'all' or a comma list of vanilla, axis-nms, rotated-nms, circle-nms, "
                                            "sianms, hybrid, gated-sianms, oracle."),
    nms_sweep: Optional[str] = typer.Option(None, help="Also run each IoU NMS at these thresholds, e.g. "
                                                       "0.05,0.1,0.2,0.3,0.5."),
    axis_mode: str = typer.Option("ignore-yaw", help="Axis-aligned box: ignore-yaw, nearest-bev or enclosing."),
    sianms_classes: str = typer.Option("car", help="Classes siaNMS (and the oracle) match (the paper: car)."),
    dis_thr: Optional[float] = typer.Option(None, help="Embedding distance above which a pair is dismissed "
                                                       "[default: the siamese checkpoint's]."),
    thresholds_from: Optional[Path] = typer.Option(None, help="A complete `sianms eval` folder of other scenes "
                                                              "(a calibration split): dis_thr and each NMS family's "
                                                              "best threshold are taken from its thresholds.json, not "
                                                              "chosen on --split [default: --nms-sweep its sweep]."),
    max_distance: float = typer.Option(50.0, help="Maximum detection distance (m): the multi-frustum circle."),
    seed: int = typer.Option(0, help="Seed of the point sampling (same seed, same results)."),
    device: str = typer.Option("cpu", help="Torch device for the networks (auto, cpu, cuda, cuda:N)."),
    pictures: int = typer.Option(4, help="Samples drawn in bird's-eye view, one panel per method (most duplicates "
                                         "first)."),
    workers: int = typer.Option(1, help="Processes for the scenes (the output does not depend on it)."),
    shard: Optional[str] = typer.Option(None, help="K/N: do only the scenes at positions K mod N (array jobs)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an evaluation of another config at --out, "
                                                              "or redo this one's finish stage."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    as_json: bool = typer.Option(False, "--json", help="Print the comparison as JSON."),
) -> None:
    """Compare duplicate handling on a split: results files, metrics per region, Table I.

    Scenes are evaluated one by one and kept, so a killed run resumes where it stopped;
    results, metrics and the table are written once every scene is done.
    """
    from sianms_cli.evaluation.job import EvalConfig, run

    config = EvalConfig(
        dataroot=str(dataroot), version=version, split=split, cache=str(cache), siamese=str(siamese),
        fpointnet=str(fpointnet), methods=methods, nms_sweep=nms_sweep, axis_mode=axis_mode,
        sianms_classes=tuple(name.strip() for name in sianms_classes.split(",") if name.strip()),
        dis_thr=dis_thr, max_distance=max_distance, seed=seed, device=device, pictures=pictures,
        thresholds_from=None if thresholds_from is None else str(thresholds_from))
    with ProgressBar(quiet) as bar:
        result = run(config, out, overwrite=overwrite, progress=bar, workers=workers, shard=shard)
    manifest = result.manifest
    if as_json:
        typer.echo(json.dumps({"out": str(result.out), "complete": manifest["complete"],
                               "missing_scenes": manifest["missing_scenes"], "table": result.table}, indent=2))
        return
    if result.table is None:
        typer.echo(f"evaluated {len(result.scenes_run)} scene(s); {manifest['scenes_finished']}/"
                   f"{manifest['scenes_expected']} done in {result.out} (results once every scene is done)")
        return
    typer.echo((Path(result.out) / "table.md").read_text())
