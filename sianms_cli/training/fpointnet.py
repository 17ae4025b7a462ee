"""Training Frustum PointNets v1 on a prepared cache (docs/methods.md#frustum-pointnets).

The network, losses, batch 32, Adam at 1e-3 and batch-norm momentum 0.5 -> 0.01 are the
original's (Qi et al., CVPR 2018, and its released training script). Its schedule is not the
default: the original halves the learning rate and the BN momentum every 800,000 samples seen,
a step counted in KITTI-sized runs that a set of a few thousand frustums never reaches. The
default ``schedule="cosine"`` spans the epochs asked for instead (:func:`schedule`): a linear
warm-up, then a cosine decay of the learning rate to 1 % and of the BN momentum to its floor.
``schedule="original"`` keeps the staircase. Every value is a config field.

Each epoch trains on the cache's single-camera frustums (streamed, :mod:`sianms_cli.data.
frustum_dataset`), then, with a validation cache, measures per class and overall: the loss,
segmentation accuracy, 3-D IoU >= 0.5 and >= 0.7 rates, centre error (m), heading-bin
accuracy and heading error (rad) both as the AOE counts it (period 2π, in [0, π]) and modulo π
(in [0, π/2]: a box turned front to back is right modulo π), so a detector that has learnt the
axis but not the direction shows as such. curves.png is redrawn every 10 epochs and at the end
(its panels take seconds). The run folder is the shared one (:mod:`.run`); the
checkpoint's ``extra`` holds what inference needs: classes, size-cluster means (l, w, h),
heading bins. Every random draw of an epoch comes from :func:`~.run.epoch_generator`, so a
resumed run ends where an uninterrupted one ends.

``multiview`` (off by default, as the paper trains) adds, for every pair of the cache's
``pairs/`` of a trained class, the union of both frustums along the multi-frustum axis, as
``sianms eval`` builds it (:mod:`sianms_cli.data.multiview`; needs ``dataroot``, the cache's
dataset, for the LiDAR sweeps). They are computed once per run, before the first epoch, into
``RUN/multiview/<shard>.parquet`` (a resumed run reuses them), and each epoch streams them
beside their shard's single frustums: same batches, sampling and augmentation. The size
clusters stay the single frustums' means (a union repeats a single frustum's object).
Validation stays on the validation cache's single frustums. metrics.csv counts the frustums
trained per epoch (``train_count``) and the union frustums among them (``train_union_count``).
Computing a union costs more than training on it (LiDAR reads, every point of the sample
projected into both cameras; figures in :mod:`sianms_cli.data.multiview`), hence once per run.

Scale: under ``torchrun --nproc-per-node K -m sianms_cli train fpointnet ...`` the training
frustums are read in ``streams`` streams (default: one per process), each rank reading only
its streams' shards (:mod:`sianms_cli.data.streams`), and each rank trains its rows of every
global batch with DistributedDataParallel; the model's random draws and batch-norm
statistics are those of the global batch (:mod:`sianms_cli.models.global_batch`) and each
rank's loss is weighted by its share, so K processes compute what one process with the same
streams computes, up to rounding. Rank 0 builds the union frustums (the others wait, then
read them), validates and writes the run.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch

from sianms_cli.data.cache import complete_manifest
from sianms_cli.data.frustum_dataset import Augmentation, FrustumSelection, class_statistics, concatenate_batches, \
    empty_batch, frustum_shards, iterate_batches
from sianms_cli.data.multiview import MultiviewSettings, build_union_shards, multiview_settings
from sianms_cli.data.streams import check_stream_count, check_streams, rank_epoch_streams, stream_steps
from sianms_cli.errors import DataFormatError, SianmsError, check_epochs, check_seed
from sianms_cli.geometry.iou3d import box_iou3d
from sianms_cli.models.fpointnet import NUM_HEADING_BINS, FPointNetV1
from sianms_cli.models.fpointnet_losses import angle_to_class, decode_boxes, fpointnet_loss
from sianms_cli.models.global_batch import BatchShare
from sianms_cli.nuscenes.classes import PAPER_CLASSES
from sianms_cli.progress import SILENT, Progress
from sianms_cli.training.precision import MixedPrecision, check_precision, float32_outputs, resolve_precision
from sianms_cli.training.run import (
    Checkpoint,
    RunFolder,
    cache_inputs,
    check_losses_finite,
    checkpoint_file,
    choose_device,
    epoch_generator,
    finish_distributed,
    init_distributed,
    load_checkpoint,
    load_state,
    plain,
    row_counts,
    seed_everything,
    set_learning_rate,
    sum_over_ranks,
)

# Size clusters for a class without a training frustum: the nuScenes means (l, w, h) MM3D uses
# as anchors. A class with neither is refused.
PRIOR_SIZES = {
    "car": (4.60718145, 1.95017717, 1.72270761),
    "pedestrian": (0.7256437, 0.66344886, 1.75748069),
    "bicycle": (1.68452161, 0.60058911, 1.27192197),
    "motorcycle": (2.09973778, 0.76279481, 1.44403034),
}
CURVES_EVERY = 10  # epochs between redraws of curves.png (about 40 panels: seconds each); also at the end
MULTIVIEW_FOLDER = "multiview"  # RUN/multiview/<shard>.parquet: the union frustums of each cache shard
MAX_POINTS = 2**16  # points a frustum is sampled to (the original: 1,024): a typo is refused, not allocated
LOSS_TERMS = ("total", "mask", "center", "stage1_center", "heading_class", "heading_residual", "size_class",
              "size_residual", "corner")


LOSS_WEIGHTS = ("box_weight", "corner_weight", "heading_class_weight")  # config fields that weight the loss terms
SCHEDULES = ("cosine", "original")
WARMUP_SHARE = 0.03  # of the run's samples (at most one epoch): Adam's early steps at the full rate shook BN
FINAL_LR_SHARE = 0.01  # the cosine schedule's last learning rate, as a share of the first


@dataclass(frozen=True)
class FPointNetConfig:
    """What `sianms train fpointnet` does; defaults are the original's (module docstring)."""

    cache: str
    val_cache: str | None = None
    classes: tuple[str, ...] = PAPER_CLASSES
    num_points: int = 1024
    min_box_height: float = 25.0  # pixels; 0 keeps every frustum
    intensity: bool = True
    flip: bool = True
    shift: bool = True
    jitter: bool = True
    epochs: int = 201
    batch_size: int = 32
    lr: float = 1e-3
    schedule: str = "cosine"  # or "original" (module docstring)
    decay_step: int = 800_000  # schedule "original": samples seen per halving of the learning rate and BN momentum
    decay_rate: float = 0.5
    bn_momentum: float = 0.5  # PyTorch momentum at the start (TF BN decay 0.5)
    bn_momentum_min: float = 0.01  # TF BN decay capped at 0.99
    box_weight: float = 1.0
    corner_weight: float = 10.0
    heading_class_weight: float = 1.0
    num_object_points: int = 512
    init: str | None = None  # weights to start from: a fpointnet run folder, checkpoint or zoo:NAME (fine-tuning)
    multiview: bool = False  # also train on the union frustums of the cache's camera pairs
    dataroot: str | None = None  # the cache's nuScenes dataroot (LiDAR sweeps); required with multiview
    max_distance: float = 50.0  # metres: multi-frustum circle radius, nuScenes' car detection range
    seed: int = 0
    device: str = "auto"
    precision: str = "auto"  # training forward passes' float type (sianms_cli.training.precision)
    streams: int | None = None  # data streams (sianms_cli.data.streams); None: one per process

    def __post_init__(self) -> None:
        object.__setattr__(self, "classes", tuple(self.classes))
        if not self.classes or len(set(self.classes)) != len(self.classes):
            raise SianmsError(f"--classes must name distinct classes, got {','.join(self.classes)}")
        for name in ("num_points", "batch_size", "decay_step", "num_object_points"):
            if getattr(self, name) < 1:
                raise SianmsError(f"--{name.replace('_', '-')} must be at least 1, got {getattr(self, name)}")
        check_epochs(self.epochs)
        if self.batch_size < 2:
            raise SianmsError("--batch-size must be at least 2 (batch norm)")
        for name in ("num_points", "num_object_points"):
            if getattr(self, name) > MAX_POINTS:
                raise SianmsError(f"--{name.replace('_', '-')} must be at most {MAX_POINTS:,}, "
                                  f"got {getattr(self, name)}")
        check_stream_count(self.streams)
        checks = [
            (self.lr > 0 and math.isfinite(self.lr), f"--lr must be positive, got {self.lr}"),
            (0 < self.decay_rate <= 1, f"--decay-rate must be in (0, 1], got {self.decay_rate}"),
            (self.min_box_height >= 0, f"--min-box-height must be >= 0, got {self.min_box_height}"),
        ]
        checks += [(math.isfinite(getattr(self, name)) and getattr(self, name) >= 0,
                    f"--{name.replace('_', '-')} must be a finite number >= 0, got {getattr(self, name)}")
                   for name in LOSS_WEIGHTS]
        for ok, message in checks:
            if not ok:
                raise SianmsError(message)
        check_seed(self.seed)
        check_precision(self.precision)
        if self.schedule not in SCHEDULES:
            raise SianmsError(f"--schedule must be one of {', '.join(SCHEDULES)}, got '{self.schedule[:40]}'")
        if self.multiview and not self.dataroot:
            raise SianmsError("--multiview needs --dataroot: the nuScenes dataroot the cache was prepared from "
                              "(union frustums are cut from its LiDAR sweeps)")
        if not (math.isfinite(self.max_distance) and self.max_distance > 0):
            raise SianmsError(f"--max-distance must be a finite number > 0, got {self.max_distance}")

    @property
    def selection(self) -> FrustumSelection:
        return FrustumSelection(self.classes, self.num_points, self.min_box_height, self.intensity)

    @property
    def augmentation(self) -> Augmentation:
        return Augmentation(self.flip, self.shift, self.jitter)


@dataclass
class FPointNetResult:
    """What a training returns: the run folder, the per-epoch history, the size clusters,
    the epochs already done when it started (resume), the model's parameter count, the
    precision it trained in."""

    out: Path
    history: list[dict[str, Any]]
    mean_sizes: np.ndarray
    resumed_from: int
    parameters: int
    precision: str = "fp32"


def schedule(config: FPointNetConfig, samples: int, total: int) -> tuple[float, float]:
    """(learning rate, BN momentum) after ``samples`` of a run's ``total`` training samples.

    ``cosine``: the learning rate rises linearly over the first :data:`WARMUP_SHARE` of the run
    (at most ``total / epochs``, one epoch), then falls along a half cosine to
    :data:`FINAL_LR_SHARE` of ``config.lr`` at ``total``; the BN momentum falls along the same
    half cosine over the whole run, from ``bn_momentum`` to ``bn_momentum_min``.
    ``original``: both halve every ``decay_step`` samples (staircase), the momentum down to its floor.
    """
    if config.schedule == "original":
        steps = samples // config.decay_step
        lr = config.lr * config.decay_rate ** steps
        return lr, max(config.bn_momentum_min, config.bn_momentum * 0.5 ** steps)
    total = max(total, 1)
    warmup = min(WARMUP_SHARE * total, total / config.epochs)
    if samples < warmup:
        return config.lr * (samples + 1) / (warmup + 1), config.bn_momentum
    lr = config.lr * (FINAL_LR_SHARE + (1 - FINAL_LR_SHARE) * half_cosine((samples - warmup) / max(total - warmup, 1)))
    momentum = config.bn_momentum_min + (config.bn_momentum - config.bn_momentum_min) * half_cosine(samples / total)
    return lr, momentum


def half_cosine(progress: float) -> float:
    """1 at the start of a span, 0 at its end (``progress`` 0 -> 1, past the end held at 0), along a half cosine."""
    return 0.5 * (1 + math.cos(math.pi * min(progress, 1.0)))


def size_clusters(config: FPointNetConfig) -> tuple[np.ndarray, np.ndarray]:
    """(counts (K,), mean (l, w, h) (K, 3)) of the training frustums; priors for empty classes."""
    counts, means = class_statistics(config.cache, config.selection)
    if counts.sum() == 0:
        raise SianmsError(f"{config.cache}: no training frustum of {', '.join(config.classes)} "
                          "(with a box, an object point and the minimum box height)")
    for k in np.flatnonzero(counts == 0):
        name = config.classes[k]
        if name not in PRIOR_SIZES:
            raise SianmsError(f"{config.cache}: no training frustum of class '{name}' to size its cluster")
        means[k] = PRIOR_SIZES[name]
    return counts, means


def loss_weights(config: FPointNetConfig) -> dict[str, float]:
    """The loss terms' weights, as :func:`sianms_cli.models.fpointnet_losses.fpointnet_loss` takes them."""
    return {name: getattr(config, name) for name in LOSS_WEIGHTS}


def to_tensors(batch: dict[str, np.ndarray], num_classes: int, device: torch.device) -> dict[str, torch.Tensor]:
    """The model's inputs and the loss's targets of a numpy batch."""
    tensor = {key: torch.as_tensor(batch[key]).to(device) for key in ("points", "seg", "class_index")}
    for key in ("center", "heading", "lwh"):
        tensor[key] = torch.as_tensor(batch[key], dtype=torch.float32).to(device)
    tensor["one_hot"] = torch.nn.functional.one_hot(tensor["class_index"], num_classes).float()
    tensor["size_class"] = tensor["class_index"]
    return tensor


def box_scores(outputs: dict[str, torch.Tensor]) -> torch.Tensor:
    """(B,) the original's 3-D box score with GT 2-D boxes (FPN-TF ``test.py``; docs/methods.md#box-score).

    log(mean object probability over the points predicted as object) + log(max heading-bin
    probability) + log(max size-cluster probability). Where no point is predicted as object
    the original's mean is undefined (NaN); the highest object probability stands in, which
    is below 0.5, so such a box ranks below any box with a mask.
    """
    object_probability = outputs["seg_logits"].softmax(dim=2)[..., 1]
    mask = outputs["mask"]
    masked_mean = (object_probability * mask).sum(dim=1) / mask.sum(dim=1).clamp(min=1)
    mask_term = torch.where(mask.any(dim=1), masked_mean, object_probability.amax(dim=1))
    return (mask_term.log() + outputs["heading_scores"].log_softmax(dim=1).amax(dim=1)
            + outputs["size_scores"].log_softmax(dim=1).amax(dim=1))


def predict(model: FPointNetV1, tensors: dict[str, torch.Tensor],
            generator: torch.Generator | None = None) -> dict[str, torch.Tensor]:
    """Boxes of a batch in the frustum frame: ``center``, ``heading``, ``lwh`` (l, w, h), ``score``,
    plus the raw outputs (the model must be in eval mode)."""
    outputs = model(tensors["points"], tensors["one_hot"], generator=generator)
    boxes = decode_boxes(outputs, model.mean_sizes, model.num_heading_bins)
    return {**outputs, **{f"box_{key}": value for key, value in boxes.items()}, "score": box_scores(outputs)}


def train_epoch(model: torch.nn.Module, optimizer: torch.optim.Optimizer, config: FPointNetConfig, epoch: int,
                rng: np.random.Generator, generator: torch.Generator, samples: int, total: int,
                device: torch.device, progress: Progress, precision: MixedPrecision, unions: Path | None = None,
                rank: int = 0, world: int = 1) -> tuple[dict[str, float], int]:
    """One pass over the training cache (and the union frustums in ``unions``, a folder of
    :func:`~sianms_cli.data.multiview.build_union_shards`); (mean loss terms weighted by batch
    size plus the frustum counts, samples seen after). ``samples`` of the run's ``total`` were
    seen before it (:func:`schedule`).

    ``rng`` is the epoch's generator: it deals the shards to ``config.streams`` streams and
    draws stream 0's batches; stream s > 0 draws from ``epoch_generator(seed, epoch, s)``.
    ``model`` is the network or, with ``world`` > 1 ranks, its DistributedDataParallel
    wrapper; each rank reads its streams and trains on its rows of every global batch
    (module docstring). A rank whose streams have run out still takes part in each step,
    with no rows and a zero loss, until every rank's have. ``precision``: the forward passes'
    autocast and the backward step.
    """
    network = model.module if world > 1 else model
    assert isinstance(network, FPointNetV1)  # the network, or the one its DDP wrapper holds
    assert config.streams is not None  # run resolves None to one stream per process
    model.train()
    streams = [iterate_batches(config.cache, config.selection, stream.batch_size, stream.rng, True,
                               config.augmentation, unions=unions, shards=stream.shards)
               for stream in rank_epoch_streams(frustum_shards(config.cache), rng,
                                                lambda s: epoch_generator(config.seed, epoch, s), config.batch_size,
                                                config.streams, rank, world)]
    sums = dict.fromkeys(LOSS_TERMS, 0.0)
    seen = union_seen = 0
    for batch, counts in stream_steps(streams, concatenate_batches, empty_batch(config.selection),
                                      lambda rows: len(rows["center"]),
                                      lambda count: row_counts(count, rank, world, device)):
        share = BatchShare.of_counts(counts, rank)
        lr, momentum = schedule(config, samples, total)
        set_learning_rate(optimizer, lr)
        network.set_bn_momentum(momentum)
        tensors = to_tensors(batch, len(config.classes), device)
        with precision.autocast():
            outputs = model(tensors["points"], tensors["one_hot"], generator=generator, share=share)
        outputs = float32_outputs(outputs)
        optimizer.zero_grad(set_to_none=True)
        if len(share):
            losses = fpointnet_loss(outputs, tensors, network.mean_sizes, **loss_weights(config))
            loss = losses["total"] * share.loss_weight(world)
            for term in LOSS_TERMS:
                sums[term] += losses[term].item() * len(share)
        else:  # no rows here: the backward pass's collectives still need this rank, with zero gradients
            loss = sum((value.sum() for value in outputs.values() if value.requires_grad),
                       torch.zeros((), device=device)).mul(0.0)
        precision.backward_step(loss, optimizer)
        seen += share.size
        union_seen += int(batch["union"].sum())
        samples += share.size
        progress.advance(share.size)
    *totals, union_total = sum_over_ranks([*(sums[term] for term in LOSS_TERMS), union_seen], device, world)
    figures = {f"train_{term}": value / max(seen, 1) for term, value in zip(LOSS_TERMS, totals)}
    return {**figures, "train_count": seen, "train_union_count": int(union_total)}, samples


def validate(model: FPointNetV1, config: FPointNetConfig, rng: np.random.Generator, generator: torch.Generator,
             device: torch.device) -> dict[str, float]:
    """Loss and box figures on the validation cache, overall and per class (module docstring)."""
    return validation_figures(validation_rows(model, config, rng, generator, device), config.classes)


def validation_figures(rows: dict[str, np.ndarray], classes: Sequence[str]) -> dict[str, float]:
    """The figures of :func:`validation_rows`' rows, overall and per class ({} without rows)."""
    if not rows:
        return {}
    metrics = _figures("val", rows, np.ones(len(rows["class"]), dtype=bool))
    for k, name in enumerate(classes):
        metrics.update(_figures(f"val_{name}", rows, rows["class"] == k))
    return metrics


@torch.no_grad()
def validation_rows(model: FPointNetV1, config: FPointNetConfig, rng: np.random.Generator,
                    generator: torch.Generator, device: torch.device) -> dict[str, np.ndarray]:
    """Per validation frustum: class index, 3-D IoU, centre error, heading error (period 2π), whether
    the heading bin is right, segmentation accuracy, its batch's loss, and the range of the box's
    centre from the camera ({} without frustums)."""
    assert config.val_cache is not None, "validation rows need a validation cache"
    model.eval()
    rows: dict[str, list[np.ndarray]] = {key: [] for key in ("class", "iou", "center", "heading", "heading_bin",
                                                             "seg", "loss", "range")}
    for batch in iterate_batches(config.val_cache, config.selection, config.batch_size, rng, False):
        tensors = to_tensors(batch, len(config.classes), device)
        prediction = predict(model, tensors, generator)
        losses = fpointnet_loss(prediction, tensors, model.mean_sizes, **loss_weights(config))
        center = prediction["box_center"].double().cpu().numpy()
        heading = prediction["box_heading"].double().cpu().numpy()
        rows["class"].append(batch["class_index"])
        rows["iou"].append(box_iou3d(center, prediction["box_lwh"].double().cpu().numpy(), heading,
                                     batch["center"], batch["lwh"], batch["heading"]))
        rows["center"].append(np.linalg.norm(center - batch["center"], axis=1))
        rows["range"].append(np.linalg.norm(batch["center"], axis=1))
        rows["heading"].append(np.abs(np.remainder(heading - batch["heading"] + np.pi, 2 * np.pi) - np.pi))
        target_bin = angle_to_class(tensors["heading"], model.num_heading_bins)[0]
        rows["heading_bin"].append((prediction["heading_scores"].argmax(dim=1) == target_bin).cpu().numpy())
        rows["seg"].append((prediction["mask"].cpu().numpy() == (batch["seg"] == 1)).mean(axis=1))
        rows["loss"].append(np.full(len(center), losses["total"].item()))
    if not rows["class"]:
        return {}
    return {key: np.concatenate(value) for key, value in rows.items()}


def _figures(prefix: str, rows: dict[str, np.ndarray], keep: np.ndarray) -> dict[str, float]:
    """The validation figures of the rows ``keep`` (NaN, written as an empty cell, where none)."""
    count = int(keep.sum())
    mean = (lambda values: float(values[keep].mean())) if count else (lambda values: math.nan)
    figures = {f"{prefix}_count": count, f"{prefix}_seg_accuracy": mean(rows["seg"]),
               f"{prefix}_iou_0.5": mean(rows["iou"] >= 0.5), f"{prefix}_iou_0.7": mean(rows["iou"] >= 0.7),
               f"{prefix}_center_error": mean(rows["center"]), f"{prefix}_heading_error": mean(rows["heading"]),
               f"{prefix}_heading_error_mod_pi": mean(np.minimum(rows["heading"], np.pi - rows["heading"])),
               f"{prefix}_heading_bin_accuracy": mean(rows["heading_bin"])}
    if prefix == "val":
        figures["val_loss"] = mean(rows["loss"])  # batch means weighted by batch size
    return figures


def load_initial_weights(model: FPointNetV1, config: FPointNetConfig) -> np.ndarray:
    """Start ``model`` from the weights of ``config.init`` (fine-tuning) and return their size
    clusters (l, w, h), which the run keeps: its size residuals are relative to them. A checkpoint
    of other classes or another shape of network is refused, naming it and the first weight that
    differs (float16 zoo weights are cast to the model's float32 as they load)."""
    assert config.init is not None, "fine-tuning needs the weights to start from"
    path = checkpoint_file(config.init)
    initial = load_checkpoint(path, "fpointnet")
    classes = initial.extra.get("classes")
    if classes != list(config.classes):
        raise DataFormatError(path, f"trained on classes {classes!r}, this run trains {list(config.classes)}: "
                              "--classes must be the same to fine-tune", field="extra.classes")
    load_state(model, initial.model, path)
    return model.mean_sizes.cpu().numpy().astype(np.float64)


def build_shared_unions(config: FPointNetConfig, folder: Path, settings: MultiviewSettings, progress: Progress,
                        rank: int, world: int) -> dict[str, int]:
    """The run's union frustums (:func:`~sianms_cli.data.multiview.build_union_shards`): rank 0
    builds them; the other ranks wait for it, then find every shard done and only count them."""
    if rank == 0:
        counts = build_union_shards(config.cache, folder, config.selection, settings, progress)
    if world > 1:
        torch.distributed.barrier()
    if rank != 0:
        counts = build_union_shards(config.cache, folder, config.selection, settings, progress)
    return counts


def run(config: FPointNetConfig, out: str | Path, *, overwrite: bool = False, resume: bool = False,
        progress: Progress = SILENT, on_epoch: Callable[[dict[str, Any]], None] | None = None) -> FPointNetResult:
    """Train Frustum PointNets v1 on ``config.cache`` into the run folder ``out``.

    Args:
        config: what to train.
        out: run folder (:class:`~sianms_cli.training.run.RunFolder`).
        overwrite: replace a finished or stopped run in ``out``.
        resume: continue the run in ``out`` from its checkpoint.
        progress: told the frustums of each epoch as they are trained.
        on_epoch: called with each finished epoch's row of metrics.csv.
    """
    for cache in (config.cache, config.val_cache):  # before the run folder exists: bad input leaves none
        if cache is not None:
            complete_manifest(cache)
    counts, mean_sizes = size_clusters(config)
    rank, world, device = init_distributed(choose_device(config.device))
    streams = world if config.streams is None else config.streams
    config = replace(config, streams=streams)
    check_streams(streams, world, config.batch_size, smallest=2)  # batch norm: two frustums per stream
    precision = MixedPrecision(resolve_precision(config.precision, device), device)
    union_settings = None
    if config.multiview:
        assert config.dataroot is not None  # __post_init__ refuses --multiview without --dataroot
        union_settings = multiview_settings(config.cache, config.dataroot, config.max_distance)
    folder = RunFolder.open(out, kind="fpointnet", config=plain(asdict(config)), overwrite=overwrite,
                            resume=resume, may_differ=("epochs", "device", "precision"),
                            added={"heading_class_weight": FPointNetConfig.heading_class_weight},
                            write=rank == 0, inputs=cache_inputs(config.cache, config.val_cache))
    with folder:
        unions, union_counts = None, {}
        if union_settings is not None:  # once per run: a resumed run finds them done (their key matches)
            unions = folder.path / MULTIVIEW_FOLDER
            union_counts = build_shared_unions(config, unions, union_settings, progress, rank, world)
        seed_everything(config.seed)
        model = FPointNetV1(torch.as_tensor(mean_sizes), 4 if config.intensity else 3,
                            num_object_points=config.num_object_points).to(device)
        # One fused kernel for every parameter: 0.6 ms a step against 2.6-3.9 ms for Adam's loop on
        # 2 CPU threads (docs/performance.md#training-sianms-train).
        optimizer = torch.optim.Adam(model.parameters(), lr=config.lr, fused=True)
        history: list[dict[str, Any]] = []
        start, samples = 0, 0
        if config.init is not None and folder.resumed is None:
            mean_sizes = load_initial_weights(model, config)
        if folder.resumed is not None:
            folder.restore(model, optimizer)
            start, history = folder.resumed.epoch, list(folder.resumed.history)
            recorded = folder.resumed.extra.get("samples")
            if not isinstance(recorded, int) or isinstance(recorded, bool) or recorded < 0:
                raise DataFormatError(folder.checkpoint_path, f"expected a sample count >= 0, got {recorded!r}",
                                      field="extra.samples")
            samples = recorded
            precision.restore(folder.resumed.extra)
        trained = torch.nn.parallel.DistributedDataParallel(model) if world > 1 else model
        total = config.epochs * (int(counts.sum()) + sum(union_counts.values()))
        for epoch in range(start, config.epochs):
            rng = epoch_generator(config.seed, epoch)
            torch.manual_seed(int(rng.integers(2**62)))  # dropout
            generator = torch.Generator(device=device).manual_seed(int(rng.integers(2**62)))  # masking
            progress.start(int(counts.sum()) + sum(union_counts.values()), "frustum",
                           f"epoch {epoch + 1}/{config.epochs}")
            row: dict[str, Any] = {"epoch": epoch + 1, "lr": schedule(config, samples, total)[0]}
            began = time.perf_counter()
            losses, samples = train_epoch(trained, optimizer, config, epoch, rng, generator, samples, total,
                                          device, progress, precision, unions, rank, world)
            row.update(losses, train_seconds=time.perf_counter() - began)
            check_losses_finite(row)
            if config.val_cache is not None and rank == 0:
                row.update(validate(model, config, rng, generator, device))
            row["seconds"] = time.perf_counter() - began
            history.append(row)
            if on_epoch is not None and rank == 0:
                on_epoch(row)
            folder.save(Checkpoint(kind="fpointnet", config=folder.config, epoch=epoch + 1, model=model.state_dict(),
                                   optimizer=optimizer.state_dict(), history=history,
                                   extra={"samples": samples, "classes": list(config.classes),
                                          "mean_sizes": mean_sizes.tolist(), "train_counts": counts.tolist(),
                                          "train_union_frustums": sum(union_counts.values()),
                                          "num_heading_bins": NUM_HEADING_BINS, **precision.checkpoint_extra()}),
                        curves=(epoch + 1) % CURVES_EVERY == 0 or epoch + 1 == config.epochs)
    finish_distributed(world)
    return FPointNetResult(Path(out), history, mean_sizes, start, sum(p.numel() for p in model.parameters()),
                           precision.name)
