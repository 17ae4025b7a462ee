"""`sianms demo`: synth → prepare → train → eval → report on a synthetic mini, in one command."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

from sianms_cli.cli._app import ProgressBar, command, use_torch_threads


@command("demo")
def demo_cli(
    out: Path = typer.Option(Path("sianms-demo"), help="Demo folder (a rerun resumes the stages not yet done)."),
    quick: bool = typer.Option(False, "--quick",
                               help="The quick profile, for CI: 2 scenes, 4 siamese epochs (with --train-fpointnet "
                                    "4 F-PointNets epochs of batch 8, 128 points per frustum; times: "
                                    "docs/performance.md)."),
    seed: Optional[int] = typer.Option(None, help="Seed of the world, the 2-D detector, the trainings and eval "
                                                  "[default: 0; 1 with --quick, whose one validation scene of "
                                                  "seed 0 holds a single car]."),
    version: str = typer.Option("v1.0-mini", help="v1.0-mini (10 scenes, 2 of them validation) or v1.0-trainval "
                                                  "(up to 850, 150/850 of them validation: a larger study)."),
    scenes: Optional[int] = typer.Option(None, help="Scenes to generate: 2-10 (v1.0-mini), 2-850 (v1.0-trainval) "
                                                    "[default: the profile's]."),
    siamese_epochs: Optional[int] = typer.Option(None, help="Siamese epochs [default: the profile's]."),
    train_fpointnet: bool = typer.Option(False, "--train-fpointnet",
                                         help="Train Frustum PointNets as a stage instead of evaluating the model "
                                              "zoo's (zoo:fpointnet-single, `sianms zoo`)."),
    fpointnet_epochs: Optional[int] = typer.Option(None, help="With --train-fpointnet: its epochs [default: the "
                                                              "profile's]."),
    precision: str = typer.Option("fp32", help="The trainings in fp32 or bf16 (bf16 only where the CPU computes "
                                               "it natively and SIANMS_NATIVE_KERNELS=1: docs/reproducibility.md)."),
    threads: Optional[int] = typer.Option(None, min=1, help="CPU threads for torch [default: torch's choice]."),
    workers: int = typer.Option(2, min=1, help="Processes for synth (the dataset does not depend on it)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a demo of another config at --out."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars or stage lines."),
    as_json: bool = typer.Option(False, "--json", help="Print the stages' times and the comparison as JSON."),
) -> None:
    """Generate a synthetic nuScenes mini, prepare it, train the siamese network, compare every
    duplicate-handling method with the model zoo's Frustum PointNets (or one trained here, with
    --train-fpointnet) and write the report: the whole study on this machine.

    Each stage prints its wall time; a rerun skips finished stages and resumes the one that
    was interrupted. Every stage's folder is an ordinary output of its own command.
    """
    from sianms_cli.demo import DemoConfig, run, stage_shares

    use_torch_threads(threads)
    config = DemoConfig(quick=quick, seed=seed, version=version, scenes=scenes, siamese_epochs=siamese_epochs,
                        fpointnet_epochs=fpointnet_epochs, precision=precision, train_fpointnet=train_fpointnet)

    def announce(stage: str, event: str, seconds: float | None) -> None:
        if quiet:
            return
        position = f"[{config.stages.index(stage) + 1}/{len(config.stages)}] {stage}"
        if event == "start":
            typer.echo(f"{position} ...", err=True)
        elif event == "done":
            typer.echo(f"{position}: done in {seconds:.1f} s", err=True)
        else:
            typer.echo(f"{position}: done earlier ({seconds or 0:.1f} s), skipped", err=True)

    with ProgressBar(quiet) as bar:
        result = run(config, out, overwrite=overwrite, progress=bar, on_stage=announce, workers=workers)
    shares = stage_shares(result.manifest)
    if as_json:
        typer.echo(json.dumps({"out": str(result.out), "config": result.manifest["config"],
                               "stages": result.manifest["stages"], "shares": shares, "table": result.table},
                              indent=2))
        return
    typer.echo((result.out / "eval" / "table.md").read_text())
    typer.echo(f"report: {result.out / 'eval' / 'report' / 'report.html'}")
    total = sum(float(state["seconds"]) for state in result.manifest["stages"].values())
    typer.echo("wall time by stage: " + ", ".join(f"{stage} {share:.0%}" for stage, share in shares.items())
               + f" (total {total / 60:.1f} min)")
