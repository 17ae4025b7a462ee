"""`sianms train ...`: the command group of the trainings (one subcommand per model).

The library is imported inside each command, so ``sianms train -h`` loads no torch.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any, Callable, Optional

import typer

from sianms_cli.cli._app import ProgressBar, command, command_group, follower_rank, use_torch_threads

train_app = command_group("train", "Train the paper's networks on a prepared cache (`sianms prepare`).")


# The options every training takes (typer reads these defaults; sharing them keeps the
# trainings' flags identical).
CACHE = typer.Option(..., help="Training cache (`sianms prepare` of a training split).")
OUT = typer.Option(..., help="Run folder: checkpoint.pt, config.json, metrics.csv, curves.png.")
SEED = typer.Option(0, help="Seed of every random source (same seed, same weights on a CPU).")
DEVICE = typer.Option("auto", help="auto (CUDA, then CPU), cpu, cuda or cuda:N.")
PRECISION = typer.Option("auto", help="Training forward passes in fp32, bf16 or fp16 (CUDA only, loss-scaled); "
                                       "auto: bf16 on GPUs that have it, else fp16; on a CPU bf16 where it "
                                       "computes it natively, else fp32. Validation runs in fp32.")
THREADS = typer.Option(None, min=1, help="CPU threads for torch [default: torch's choice].")
STREAMS = typer.Option(None, help="Training data streams, each reading its own shards; under torchrun each process "
                                  "runs streams/processes of them. One process with --streams K trains what K "
                                  "processes train [default: one per process].")
RESUME = typer.Option(False, "--resume", help="Continue the run at --out from its last checkpoint.")
OVERWRITE = typer.Option(False, "--overwrite", help="Replace the run at --out.")
QUIET = typer.Option(False, "--quiet", help="No progress bar, no per-epoch lines.")
AS_JSON = typer.Option(False, "--json", help="Print the result as JSON (and nothing else) on stdout.")


def train_command(name: str) -> Callable[[Callable], Callable]:
    """Register ``sianms train NAME`` with :func:`command`'s error handling (one ``error:`` line, exit 2)."""
    return command(name, train_app)


def _widths(text: str, flag: str) -> tuple[int, ...]:
    """'128,128' -> (128, 128); a malformed list is a user error naming the flag."""
    from sianms_cli.errors import SianmsError

    try:
        return tuple(int(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise SianmsError(f"{flag} must be comma-separated integers, got '{text}'") from None


def _note(bar: ProgressBar, text: str) -> None:
    """A line on stderr above the progress bar (tqdm.write keeps the bar intact)."""
    if bar.bar is not None:
        bar.bar.write(text, file=sys.stderr)
    else:
        typer.echo(text, err=True)


def _figure(value: Any) -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.3f}"


def _json_value(value: Any) -> Any:
    """NaN as null: JSON has no NaN."""
    if isinstance(value, float) and math.isnan(value):
        return None
    if isinstance(value, dict):
        return {key: _json_value(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_json_value(item) for item in value]
    return value


# --------------------------------------------------------------------------- siamese


@train_command("siamese")
def siamese_cli(
    cache: Path = CACHE,
    val_cache: Optional[Path] = typer.Option(None, help="Validation cache: per-epoch AUC, matching P/R/F1, dis_thr."),
    out: Path = OUT,
    dim: int = typer.Option(100, help="Embedding size d (paper: 100)."),
    conv_channels: str = typer.Option("128,128", help="Widths of the two conv + max-pool groups."),
    hidden: str = typer.Option("256", help="Widths of the hidden fully connected layers."),
    alpha: float = typer.Option(1.0, help="Positive margin of eq. (6)."),
    beta: float = typer.Option(3.0, help="Negative margin of eq. (6)."),
    lr: float = typer.Option(1e-4, help="Adam learning rate (paper: 1e-4; the synthetic demo: 1e-3)."),
    lr_decay: float = typer.Option(0.1, help="Learning-rate factor every --lr-step epochs."),
    lr_step: int = typer.Option(8, help="Epochs between learning-rate decays."),
    epochs: int = typer.Option(25, help="Epochs, each takes every reference instance once (paper: 25; "
                                        "the synthetic demo: 12)."),
    batch_size: int = typer.Option(8, help="Reference instances per step (N)."),
    standardize: bool = typer.Option(False, "--standardize/--no-standardize",
                                     help="Standardise each input channel with the training cache's mean and std "
                                          "(kept in the checkpoint; not in the paper)."),
    seed: int = SEED,
    device: str = DEVICE,
    precision: str = PRECISION,
    threads: Optional[int] = THREADS,
    streams: Optional[int] = STREAMS,
    sweep_dims: Optional[str] = typer.Option(None, help="Train one model per d (e.g. 5,10,20,50,100,200,500,1000) "
                                                         "into --out/d<d>/ and tabulate them in sweep.md/json."),
    resume: bool = RESUME,
    overwrite: bool = OVERWRITE,
    quiet: bool = QUIET,
    as_json: bool = AS_JSON,
) -> None:
    """Train the siamese re-identification network (paper §III-B, §IV) with online hard negatives."""
    from sianms_cli.training.siamese import SiameseConfig, parse_dims, run, sweep, sweep_markdown

    use_torch_threads(threads)
    follower = follower_rank() is not None
    quiet = quiet or follower
    config = SiameseConfig(
        cache=str(cache), val_cache=None if val_cache is None else str(val_cache), dim=dim,
        conv_channels=_widths(conv_channels, "--conv-channels"), hidden=_widths(hidden, "--hidden"),
        alpha=alpha, beta=beta, lr=lr, lr_decay=lr_decay, lr_step=lr_step, epochs=epochs, batch_size=batch_size,
        seed=seed, device=device, precision=precision, standardize=standardize, streams=streams)

    def report_epoch(row: dict[str, Any]) -> None:
        if quiet:
            return
        validation = (f"; val AUC {_figure(row['val_auc'])} (baseline {_figure(row['baseline_auc'])}), "
                      f"F1 {_figure(row['val_f1'])} at dis_thr {_figure(row['val_dis_thr'])}"
                      if "val_auc" in row else "")
        _note(bar, f"epoch {row['epoch']}/{epochs}: loss {row['train_loss']:.4f} "
                   f"(positive {row['train_positive_loss']:.4f}, negative {row['train_negative_loss']:.4f})"
                   f"{validation}")

    bar = ProgressBar(quiet)
    if sweep_dims is not None:
        dims = parse_dims(sweep_dims)
        with bar:
            rows = sweep(config, dims, out, overwrite=overwrite, resume=resume, progress=bar, on_epoch=report_epoch)
        if not follower:
            typer.echo(json.dumps(_json_value({"out": str(out), "rows": rows}), indent=2) if as_json
                       else f"sweep of d = {sweep_dims} in {out}:\n" + sweep_markdown(rows).rstrip())
        return
    with bar:
        result = run(config, out, overwrite=overwrite, resume=resume, progress=bar, on_epoch=report_epoch)
    if follower:
        return
    if as_json:
        typer.echo(json.dumps(_json_value({
            "out": str(result.out), "epochs_run": result.epochs_run, "resumed_from": result.resumed_from,
            "parameters": result.parameters, "precision": result.precision, "dis_thr": result.dis_thr,
            "metrics": result.metrics,
        }), indent=2))
        return
    metrics = result.metrics
    lines = [f"trained epochs {result.resumed_from + 1}-{metrics.get('epoch', result.resumed_from)} into {result.out} "
             f"({result.parameters:,} parameters, {result.precision}); dis_thr {result.dis_thr:.3f}"]
    if not result.epochs_run:
        lines = [f"{result.out} already holds {result.resumed_from} epochs; nothing to do"]
    if "val_auc" in metrics:
        for name, prefix in (("siamese", "val"), ("baseline (mean-pooled ROI, nearest neighbour)", "baseline")):
            lines.append(
                f"  {name}: AUC {_figure(metrics[f'{prefix}_auc'])}, distance positive/negative median "
                f"{_figure(metrics[f'{prefix}_positive_distance_p50'])}/"
                f"{_figure(metrics[f'{prefix}_negative_distance_p50'])}, "
                f"matching P/R/F1 {_figure(metrics[f'{prefix}_precision'])}/{_figure(metrics[f'{prefix}_recall'])}/"
                f"{_figure(metrics[f'{prefix}_f1'])} at dis_thr {_figure(metrics[f'{prefix}_dis_thr'])} "
                f"({metrics[f'{prefix}_match_pairs']} true pairs among overlap candidates)")
    typer.echo("\n".join(lines))


# --------------------------------------------------------------------------- fpointnet

@train_command("fpointnet")
def fpointnet_cli(
    cache: Path = CACHE,
    val_cache: Optional[Path] = typer.Option(None, help="Validation cache: per-epoch IoU rates, errors, per class."),
    out: Path = OUT,
    classes: str = typer.Option("car,pedestrian,bicycle", help="Cache classes, in one-hot order (bicycle = cyclist)."),
    num_points: int = typer.Option(1024, help="Points drawn per frustum (original: 1,024; fewer for CPU runs)."),
    num_object_points: int = typer.Option(512, help="Masked points passed to the T-Net and box net (original: 512)."),
    min_box_height: float = typer.Option(25.0, help="Minimum 2-D box height in pixels (original: 25; 0 keeps all)."),
    intensity: bool = typer.Option(True, "--intensity/--no-intensity", help="Use the intensity channel."),
    flip: bool = typer.Option(True, "--flip/--no-flip", help="Random flip augmentation."),
    shift: bool = typer.Option(True, "--shift/--no-shift", help="Random depth-shift augmentation."),
    jitter: bool = typer.Option(True, "--jitter/--no-jitter",
                                help="Frustum-axis jitter (stands in for 2-D box jitter)."),
    epochs: int = typer.Option(201, help="Epochs (original: 201)."),
    batch_size: int = typer.Option(32, help="Frustums per step (original: 32)."),
    lr: float = typer.Option(1e-3, help="Adam learning rate."),
    schedule: str = typer.Option("cosine", help="cosine: warm-up, then learning rate and BN momentum decay over "
                                                "the epochs asked for; original: halved every --decay-step samples."),
    decay_step: int = typer.Option(800_000, help="With --schedule original: samples seen per learning-rate and "
                                                 "BN-momentum step."),
    decay_rate: float = typer.Option(0.5, help="With --schedule original: learning-rate factor per step."),
    box_weight: float = typer.Option(1.0, help="Weight of the box terms (λ)."),
    corner_weight: float = typer.Option(10.0, help="Weight of the corner loss inside λ."),
    heading_class_weight: float = typer.Option(1.0, help="Weight of the heading-bin loss inside λ (the only term "
                                                         "that tells front from back)."),
    init: Optional[str] = typer.Option(None, help="Start from these weights (fine-tuning): a `train fpointnet` run "
                                                  "folder, its checkpoint.pt, or zoo:NAME (`sianms zoo`)."),
    multiview: bool = typer.Option(False, "--multiview", help="Also train on the union frustum of every cache pair "
                                                              "on the multi-frustum axis, as siaNMS feeds it."),
    dataroot: Optional[Path] = typer.Option(None, help="With --multiview: the dataroot the cache was prepared from "
                                                       "(its LiDAR)."),
    max_distance: float = typer.Option(50.0, help="With --multiview: radius of the multi-frustum circle, metres."),
    seed: int = SEED,
    device: str = DEVICE,
    precision: str = PRECISION,
    threads: Optional[int] = THREADS,
    streams: Optional[int] = STREAMS,
    resume: bool = RESUME,
    overwrite: bool = OVERWRITE,
    quiet: bool = QUIET,
    as_json: bool = AS_JSON,
) -> None:
    """Train Frustum PointNets v1 (Qi et al., CVPR 2018) on the cache's single-camera frustums
    (and, with --multiview, the union frustums of its cross-camera pairs)."""
    from sianms_cli.training.fpointnet import FPointNetConfig, run

    use_torch_threads(threads)
    follower = follower_rank() is not None
    quiet = quiet or follower
    config = FPointNetConfig(
        cache=str(cache), val_cache=None if val_cache is None else str(val_cache),
        classes=tuple(name.strip() for name in classes.split(",") if name.strip()), num_points=num_points,
        num_object_points=num_object_points, min_box_height=min_box_height, intensity=intensity, flip=flip,
        shift=shift, jitter=jitter, epochs=epochs, batch_size=batch_size, lr=lr, schedule=schedule,
        decay_step=decay_step,
        decay_rate=decay_rate, box_weight=box_weight, corner_weight=corner_weight,
        heading_class_weight=heading_class_weight, init=init, multiview=multiview,
        dataroot=None if dataroot is None else str(dataroot), max_distance=max_distance, seed=seed, device=device,
        precision=precision, streams=streams)

    def report_epoch(row: dict[str, Any]) -> None:
        if quiet:
            return
        validation = (f"; val IoU>=0.5 {_figure(row['val_iou_0.5'])}, >=0.7 {_figure(row['val_iou_0.7'])}, "
                      f"centre {_figure(row['val_center_error'])} m, heading {_figure(row['val_heading_error'])} rad "
                      f"({_figure(row['val_heading_error_mod_pi'])} modulo π, bin accuracy "
                      f"{_figure(row['val_heading_bin_accuracy'])}), seg {_figure(row['val_seg_accuracy'])}"
                      if "val_iou_0.5" in row else "")
        typer.echo(f"epoch {row['epoch']}/{epochs}: loss {row['train_total']:.4f} "
                   f"(mask {row['train_mask']:.4f}, heading class {row['train_heading_class']:.4f}, "
                   f"corner {row['train_corner']:.4f}){validation}", err=True)

    with ProgressBar(quiet) as bar:
        result = run(config, out, overwrite=overwrite, resume=resume, progress=bar, on_epoch=report_epoch)
    if follower:
        return
    metrics = result.history[-1] if result.history else {}
    if as_json:
        typer.echo(json.dumps(_json_value({
            "out": str(result.out), "epochs_run": list(range(result.resumed_from + 1, len(result.history) + 1)),
            "resumed_from": result.resumed_from, "parameters": result.parameters, "precision": result.precision,
            "mean_sizes_lwh": dict(zip(config.classes, result.mean_sizes.tolist())), "metrics": metrics,
        }), indent=2))
        return
    if len(result.history) == result.resumed_from:
        typer.echo(f"{result.out} already holds {result.resumed_from} epochs; nothing to do")
        return
    lines = [f"trained epochs {result.resumed_from + 1}-{len(result.history)} into {result.out} "
             f"({result.parameters:,} parameters, {result.precision})"]
    if "val_iou_0.5" in metrics:
        for name in ("", *config.classes):
            prefix = f"val_{name}" if name else "val"
            lines.append(f"  {name or 'all'} ({metrics[f'{prefix}_count']} frustums): IoU>=0.5 "
                         f"{_figure(metrics[f'{prefix}_iou_0.5'])}, >=0.7 {_figure(metrics[f'{prefix}_iou_0.7'])}, "
                         f"centre {_figure(metrics[f'{prefix}_center_error'])} m, "
                         f"heading {_figure(metrics[f'{prefix}_heading_error'])} rad "
                         f"({_figure(metrics[f'{prefix}_heading_error_mod_pi'])} modulo π), "
                         f"seg accuracy {_figure(metrics[f'{prefix}_seg_accuracy'])}")
    typer.echo("\n".join(lines))
