"""`sianms train siamese`: the re-identification network of paper §III-B and §IV (docs/methods.md#sianms).

Training: the encoder of :mod:`sianms_cli.models.siamese` on the cache's ROI features, batches
of N reference instances paired online (:mod:`sianms_cli.data.siamese`): the candidates of each
reference's negative instance are embedded without gradients, the highest-loss (nearest) one
is kept, and eq. (6) is back-propagated through the reference, the positive and that negative.
Defaults are the paper's: Adam, lr 1e-4 × 0.1 every 8 epochs, 25 epochs, batch 8.
``standardize`` (off by default, the paper's raw features) standardises each input channel
with the training cache's statistics (:func:`~sianms_cli.data.siamese.feature_statistics`).

Validation each epoch (``val_cache``), per sample and contiguous camera pair: distance
distributions and ROC AUC of every labelled cross-camera pair; the matching inference will do
among the pair's overlap candidates, scored against instance identity at the ``dis_thr`` that
maximises F1 (stored in the checkpoint for ``eval``); the same figures for a baseline of
mean-pooled ROI features. Inference: :func:`load_encoder` and :func:`embed`.

Scale: the caches stream scene by scene in ``streams`` streams (:mod:`sianms_cli.data.streams`);
under ``torchrun`` each rank reads only its streams' scenes and trains its rows of every global
batch with DistributedDataParallel; rank 0 validates and writes the run folder.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment
from scipy.stats import rankdata

from sianms_cli.data.cache import complete_manifest
from sianms_cli.data.siamese import PairingBatch, Scene, cache_feature_shape, epoch_batches, feature_statistics, \
    hardest_candidates, iter_scenes, shard_paths
from sianms_cli.data.streams import check_stream_count, check_streams, rank_epoch_streams, stream_steps
from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError, check_epochs, check_seed
from sianms_cli.json_stream import is_finite_number
from sianms_cli.io import make_folder, partial_of, read_json, real_path, write_json, write_text
from sianms_cli.models.losses import double_margin_loss, pair_distances, positive_terms
from sianms_cli.models.siamese import SiameseEncoder, parameter_count
from sianms_cli.progress import SILENT, Progress
from sianms_cli.training.precision import MixedPrecision, check_precision, resolve_precision
from sianms_cli.training.run import Checkpoint, RunFolder, cache_inputs, check_losses_finite, \
    checkpoint_file, choose_device, epoch_generator, finish_distributed, init_distributed, load_checkpoint, \
    load_state, plain, row_counts, seed_everything, set_learning_rate, step_decay, sum_over_ranks, writes_outputs

KIND = "siamese"
MAX_WIDTH = 2**16  # a layer width past any sweep (the paper's: 100 to 256): a typo is refused, not allocated
MAX_MLP_WEIGHTS = 10**9
"""Weights between the MLP's hidden layers and the embedding: 4 GB in float32 and three times that
with Adam's moments. Every width may be within MAX_WIDTH and their products still exhaust memory
(four layers of 65,536 had been killed by the OOM killer, leaving config.json behind)."""
MAX_MARGIN = 1e6  # --beta: a distance no embedding reaches; the loss squares it in float32 (max 3.4e38)
THRESHOLD_STEPS = 64  # dis_thr candidates: quantiles of the validation candidates' distances
EMBED_CHUNK = 512  # detections embedded per forward pass at validation
CURVES = (  # curves.png panels: (title, metrics.csv columns drawn together)
    ("loss per reference, eq. (6)", ("train_loss", "train_positive_loss", "train_negative_loss")),
    ("val ROC AUC", ("val_auc", "baseline_auc")),
    ("val matching F1 at best dis_thr", ("val_f1", "baseline_f1")),
    ("val distances (learned)", ("val_positive_distance_p50", "val_negative_distance_p50", "val_dis_thr")),
    ("val precision / recall", ("val_precision", "val_recall")),
    ("learning rate", ("lr",)),
)


@dataclass(frozen=True)
class SiameseConfig:
    """What `sianms train siamese` trains; defaults are the paper's (its §IV-A, §IV-C)."""

    cache: str
    val_cache: str | None = None
    dim: int = 100
    conv_channels: tuple[int, ...] = (128, 128)
    hidden: tuple[int, ...] = (256,)
    alpha: float = 1.0
    beta: float = 3.0
    lr: float = 1e-4
    lr_decay: float = 0.1
    lr_step: int = 8
    epochs: int = 25
    batch_size: int = 8
    seed: int = 0
    device: str = "auto"
    precision: str = "auto"  # training forward passes' float type (sianms_cli.training.precision)
    standardize: bool = False
    streams: int | None = None  # data streams (sianms_cli.data.streams); None: one per process

    def __post_init__(self) -> None:
        object.__setattr__(self, "conv_channels", tuple(int(v) for v in self.conv_channels))
        object.__setattr__(self, "hidden", tuple(int(v) for v in self.hidden))
        checks = [
            (1 <= self.dim <= MAX_WIDTH, f"--dim must be in [1, {MAX_WIDTH}], got {self.dim}"),
            (len(self.conv_channels) == 2 and all(1 <= width <= MAX_WIDTH for width in self.conv_channels),
             f"--conv-channels must be two widths in [1, {MAX_WIDTH}] (Fig. 4: two conv groups), "
             f"got {self.conv_channels}"),
            (all(1 <= width <= MAX_WIDTH for width in self.hidden),
             f"--hidden widths must be in [1, {MAX_WIDTH}], got {self.hidden}"),
            (0 <= self.alpha < self.beta <= MAX_MARGIN,
             f"--alpha and --beta need 0 <= alpha < beta <= {MAX_MARGIN:g}, got {self.alpha}, {self.beta}"),
            (_mlp_weights(self.hidden, self.dim) <= MAX_MLP_WEIGHTS,
             f"--hidden {','.join(map(str, self.hidden))} and --dim {self.dim} make "
             f"{_mlp_weights(self.hidden, self.dim):,} weights between the layers; at most {MAX_MLP_WEIGHTS:,}"),
            (self.lr > 0 and math.isfinite(self.lr), f"--lr must be positive, got {self.lr}"),
            (0 < self.lr_decay <= 1, f"--lr-decay must be in (0, 1], got {self.lr_decay}"),
            (self.lr_step >= 1, f"--lr-step must be at least 1, got {self.lr_step}"),
            (self.batch_size >= 1, f"--batch-size must be at least 1, got {self.batch_size}"),
        ]
        for ok, message in checks:
            if not ok:
                raise SianmsError(message)
        check_epochs(self.epochs)
        check_seed(self.seed)
        check_precision(self.precision)
        check_stream_count(self.streams)

    def resolved(self) -> dict[str, Any]:
        """The config as plain types, paths absolute (config.json and the checkpoint)."""
        data = plain(asdict(self))
        data["cache"] = str(real_path(self.cache))
        data["val_cache"] = None if self.val_cache is None else str(real_path(self.val_cache))
        return data


def _mlp_weights(hidden: tuple[int, ...], dim: int) -> int:
    widths = (*hidden, dim)
    return sum(a * b for a, b in zip(widths, widths[1:]))


def build_model(config: SiameseConfig | dict[str, Any], feature_shape: tuple[int, int, int]) -> SiameseEncoder:
    """The encoder a config describes (from a checkpoint's config dict too)."""
    def get(key: str) -> Any:
        return config[key] if isinstance(config, dict) else getattr(config, key)

    return SiameseEncoder(feature_shape, dim=get("dim"), conv_channels=tuple(get("conv_channels")),
                          hidden=tuple(get("hidden")))


# --------------------------------------------------------------------------- training


def _tensor(features: np.ndarray, device: torch.device) -> torch.Tensor:
    return torch.from_numpy(features.astype(np.float32)).to(device)


def train_step(model: torch.nn.Module, optimizer: torch.optim.Optimizer, batch: PairingBatch,
               config: SiameseConfig, device: torch.device, precision: MixedPrecision,
               world: int = 1) -> dict[str, float]:
    """One step of paper §IV-B on a batch (this rank's share of it); the summed terms and the mining counts.

    The candidates are scored with the current weights without gradients (no layer behaves
    differently in training, so the scores equal the training forward's), then only the
    chosen negative joins the backward pass. Under DistributedDataParallel (``world`` > 1)
    the loss is scaled by ``world`` so the averaged gradient is that of eq. (6)'s sum over
    the global batch, as in one process; a rank whose share is empty still joins the
    gradient exchange with a zero loss. ``precision``: the forward passes' autocast and the
    backward step; distances and the loss are computed in float32.
    """
    model.train()
    encoder = model.module if world > 1 else model
    assert isinstance(encoder, SiameseEncoder)  # the encoder, or the one its DDP wrapper holds
    k = len(batch)
    reference, positive = _tensor(batch.reference, device), _tensor(batch.positive, device)
    if k:
        items = torch.from_numpy(batch.candidate_item).to(device)
        with torch.no_grad(), precision.autocast():
            embedded_references, embedded_candidates = encoder(reference), encoder(_tensor(batch.candidates, device))
        distances = pair_distances(embedded_references.float()[items], embedded_candidates.float())
        chosen = hardest_candidates(distances.cpu().numpy(), batch.candidate_item, k)
        negative = _tensor(batch.candidates[chosen], device)
    else:
        negative = reference
    with precision.autocast():
        embedded = model(torch.cat([reference, positive, negative]))
    embedded = embedded.float()
    loss = double_margin_loss(embedded[:k], embedded[k:2 * k], embedded[2 * k:], config.alpha, config.beta)
    optimizer.zero_grad(set_to_none=True)
    precision.backward_step(loss * world, optimizer)
    with torch.no_grad():
        positive_sum = positive_terms(pair_distances(embedded[:k], embedded[k:2 * k]), config.alpha).sum().item()
    return {"loss": loss.item(), "positive": positive_sum, "negative": loss.item() - positive_sum,
            "items": k, "fallback": int(batch.fallback.sum()), "candidates": len(batch.candidate_item)}


def train_epoch(model: torch.nn.Module, optimizer: torch.optim.Optimizer, config: SiameseConfig,
                device: torch.device, precision: MixedPrecision, epoch: int, rank: int = 0,
                world: int = 1) -> dict[str, float]:
    """One epoch over the training cache; the mean per reference of eq. (6) and its two terms.

    The epoch's generator deals the scenes to ``config.streams`` streams and pairs stream 0's;
    stream s > 0 pairs with ``epoch_generator(seed, epoch, s)``. Each rank reads only its
    streams' scenes and trains on its rows of every global batch (:mod:`sianms_cli.data.
    streams`), so K processes compute what one process with the same streams computes.
    """
    assert config.streams is not None  # run resolves None to one stream per process
    rng = epoch_generator(config.seed, epoch)
    streams = [epoch_batches(config.cache, stream.batch_size, stream.rng, shards=stream.shards)
               for stream in rank_epoch_streams(shard_paths(config.cache), rng,
                                                lambda s: epoch_generator(config.seed, epoch, s), config.batch_size,
                                                config.streams, rank, world)]
    names = ("loss", "positive", "negative", "items", "fallback", "candidates")
    totals = dict.fromkeys(names, 0.0)
    empty = PairingBatch.empty(cache_feature_shape(config.cache))
    for batch, _ in stream_steps(streams, PairingBatch.concatenate, empty, len,
                                 lambda count: row_counts(count, rank, world, device)):
        for key, value in train_step(model, optimizer, batch, config, device, precision, world).items():
            totals[key] += value
    totals = dict(zip(names, sum_over_ranks([totals[name] for name in names], device, world)))
    if totals["items"] == 0:
        raise SianmsError(f"{config.cache}: no reference instance with a positive and a negative "
                          "(the cache has no cross-camera pairs with another instance in the contiguous camera)")
    n = totals["items"]
    return {"train_loss": totals["loss"] / n, "train_positive_loss": totals["positive"] / n,
            "train_negative_loss": totals["negative"] / n, "train_references": int(n),
            "train_candidates_per_negative": totals["candidates"] / n, "negative_fallback": totals["fallback"] / n}


# --------------------------------------------------------------------------- validation


@dataclass
class PairGroup:
    """One sample's contiguous pair (A, B): distances and same-instance truth.

    ``all_*``: detections with an instance, every A × B (distance figures);
    ``match_*``: the overlap candidates of A × B, every detection (matching figures).
    """

    all_distance: np.ndarray
    all_same: np.ndarray
    match_distance: np.ndarray
    match_same: np.ndarray


def scene_groups(scene: Scene, embedding: np.ndarray) -> list[PairGroup]:
    """The :class:`PairGroup` of every sample × contiguous pair of a scene, from its embeddings (N, d)."""
    groups = []
    for pair, in_overlap in scene.overlap.items():
        camera_a, camera_b = pair.split("|")
        for sample in np.unique(scene.sample):
            here = scene.sample == sample
            a, b = here & (scene.camera == camera_a), here & (scene.camera == camera_b)
            if not (a.any() and b.any()):
                continue
            labelled = scene.instance >= 0
            labelled_a, labelled_b = np.flatnonzero(a & labelled), np.flatnonzero(b & labelled)
            match_a, match_b = np.flatnonzero(a & in_overlap), np.flatnonzero(b & in_overlap)
            groups.append(PairGroup(*_cross(scene, embedding, labelled_a, labelled_b),
                                    *_cross(scene, embedding, match_a, match_b)))
    return groups


def _cross(scene: Scene, embedding: np.ndarray, rows_a: np.ndarray, rows_b: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """(len(a), len(b)) distances and same-instance (both labelled) matrices."""
    distance = np.linalg.norm(embedding[rows_a, None, :] - embedding[None, rows_b, :], axis=-1)
    ia, ib = scene.instance[rows_a], scene.instance[rows_b]
    return distance, (ia[:, None] == ib[None, :]) & (ia[:, None] >= 0)


def roc_auc(positive: np.ndarray, negative: np.ndarray) -> float:
    """P(a positive is nearer than a negative), ties count ½ (Mann–Whitney); NaN without both kinds."""
    if len(positive) == 0 or len(negative) == 0:
        return float("nan")
    ranks = rankdata(np.concatenate([-positive, -negative]))
    return float((ranks[:len(positive)].sum() - len(positive) * (len(positive) + 1) / 2)
                 / (len(positive) * len(negative)))


def match_counts(distance: np.ndarray, same: np.ndarray, threshold: float) -> tuple[int, int]:
    """(matches kept, right matches) of the optimal assignment under ``threshold``.

    Costs above the threshold are clipped to threshold + 1e-5 before solving and the pairs
    assigned at such a cost dropped (DeepSORT's ``min_cost_matching``), so the assignment
    never fails and never prefers a forbidden pair.
    """
    if distance.size == 0:
        return 0, 0
    rows, cols = linear_sum_assignment(np.minimum(distance, threshold + 1e-5))
    keep = distance[rows, cols] <= threshold
    return int(keep.sum()), int(same[rows[keep], cols[keep]].sum())


def matching_scores(groups: list[PairGroup], threshold: float) -> dict[str, float]:
    """Precision, recall and F1 of the matching at ``threshold`` over all groups."""
    kept = right = 0
    for group in groups:
        k, r = match_counts(group.match_distance, group.match_same, threshold)
        kept, right = kept + k, right + r
    truth = sum(int(group.match_same.sum()) for group in groups)
    precision = right / kept if kept else float("nan")
    recall = right / truth if truth else float("nan")
    f1 = 2 * right / (kept + truth) if kept + truth else float("nan")
    return {"precision": precision, "recall": recall, "f1": f1}


def best_threshold(groups: list[PairGroup], default: float) -> tuple[float, dict[str, float]]:
    """The ``dis_thr`` that maximises the matching F1 (the smallest on ties) and its scores.

    Candidates: ``default`` and quantiles of every candidate distance. Without a single
    ground-truth pair among the candidates F1 is undefined and ``default`` is kept.
    """
    distances = np.concatenate([g.match_distance.ravel() for g in groups] + [np.zeros(0)])
    quantiles = np.quantile(distances, np.linspace(0, 1, THRESHOLD_STEPS)) if len(distances) else np.zeros(0)
    candidates = np.unique(np.concatenate([[default], quantiles]))
    best = (default, matching_scores(groups, default))
    for threshold in candidates:
        scores = matching_scores(groups, float(threshold))
        if not math.isnan(scores["f1"]) and (math.isnan(best[1]["f1"]) or scores["f1"] > best[1]["f1"]
                                             or (scores["f1"] == best[1]["f1"] and threshold < best[0])):
            best = (float(threshold), scores)
    return best


def summarize(groups: list[PairGroup], default_threshold: float, prefix: str) -> dict[str, float]:
    """Distance distributions, ROC AUC and the matching at the best ``dis_thr``, keys prefixed."""
    distances = np.concatenate([g.all_distance.ravel() for g in groups] + [np.zeros(0)])
    same = np.concatenate([g.all_same.ravel() for g in groups] + [np.zeros(0, dtype=bool)])
    positive, negative = distances[same], distances[~same]
    threshold, scores = best_threshold(groups, default_threshold)
    figures = {"auc": roc_auc(positive, negative), "positives": len(positive), "negatives": len(negative)}
    for name, values in (("positive", positive), ("negative", negative)):
        figures[f"{name}_distance_mean"] = float(values.mean()) if len(values) else float("nan")
        for q in (10, 50, 90):
            figures[f"{name}_distance_p{q}"] = float(np.percentile(values, q)) if len(values) else float("nan")
    figures |= {"dis_thr": threshold, **scores,
                "match_pairs": sum(int(g.match_same.sum()) for g in groups)}
    return {f"{prefix}_{key}": value for key, value in figures.items()}


def embed_scene(model: SiameseEncoder, scene: Scene, device: torch.device) -> np.ndarray:
    """(N, d) float64 embeddings of a scene's detections (:func:`embed` on the model's device)."""
    return embed(model, scene.features, batch=EMBED_CHUNK).astype(np.float64)


def validate(model: SiameseEncoder, config: SiameseConfig, device: torch.device) -> dict[str, float]:
    """The learned embedding's validation figures (``val_*``), scene by scene."""
    assert config.val_cache is not None, "validation needs a validation cache"
    groups = []
    for scene in iter_scenes(config.val_cache):
        groups += scene_groups(scene, embed_scene(model, scene, device))
    return summarize(groups, (config.alpha + config.beta) / 2, "val")


def baseline(cache: str) -> dict[str, float]:
    """The same figures (``baseline_*``) for mean-pooled ROI features and nearest neighbours."""
    groups = []
    for scene in iter_scenes(cache):
        pooled = scene.features.astype(np.float64).mean(axis=(2, 3))
        groups += scene_groups(scene, pooled)
    distances = np.concatenate([g.all_distance.ravel() for g in groups] + [np.zeros(1)])
    return summarize(groups, float(np.median(distances)), "baseline")


# --------------------------------------------------------------------------- the run


@dataclass
class SiameseResult:
    """What a run did: where, which epochs, the last epoch's figures, the chosen ``dis_thr``, the
    precision it trained in."""

    out: Path
    epochs_run: list[int]
    resumed_from: int
    metrics: dict[str, Any]
    baseline: dict[str, float]
    dis_thr: float
    parameters: int
    history: list[dict[str, Any]] = field(default_factory=list)
    precision: str = "fp32"


def run(config: SiameseConfig, out: str | Path, *, overwrite: bool = False, resume: bool = False,
        progress: Progress = SILENT, on_epoch: Callable[[dict[str, Any]], None] | None = None) -> SiameseResult:
    """Train the siamese network of ``config`` into the run folder ``out``.

    Args:
        config: what to train.
        out: run folder (see :mod:`sianms_cli.training.run`).
        overwrite: replace a run already at ``out``.
        resume: continue the run at ``out`` from its last checkpoint (same config; ``epochs``
            and ``device`` may differ); ends bit-for-bit where an uninterrupted run ends on a CPU.
        progress: told the epochs to run, then each one done.
        on_epoch: called with each finished epoch's metrics row (the CLI prints it).
    """
    for cache in (config.cache, config.val_cache):  # before the run folder exists: bad input leaves none
        if cache is not None:
            complete_manifest(cache)
    feature_shape = cache_feature_shape(config.cache)
    if config.val_cache is not None and cache_feature_shape(config.val_cache) != feature_shape:
        raise SianmsError(f"--val-cache holds ROI features of shape {cache_feature_shape(config.val_cache)}, "
                          f"--cache {feature_shape}: prepare both with the same backbone and --roi-size")
    rank, world, device = init_distributed(choose_device(config.device))
    streams = world if config.streams is None else config.streams
    config = replace(config, streams=streams)
    check_streams(streams, world, config.batch_size, smallest=1)
    precision = MixedPrecision(resolve_precision(config.precision, device), device)
    resolved = config.resolved() | {"feature_shape": list(feature_shape)}
    folder = RunFolder.open(out, kind=KIND, config=resolved, overwrite=overwrite, resume=resume,
                            may_differ=("epochs", "device", "precision"), write=rank == 0,
                            inputs=cache_inputs(config.cache, config.val_cache))
    folder.panels = CURVES
    validating = config.val_cache is not None and rank == 0
    with folder:
        seed_everything(config.seed)
        model = build_model(config, feature_shape)
        if config.standardize and folder.resumed is None:  # a resumed run's statistics are in its weights
            mean, std, _ = feature_statistics(config.cache)
            model.set_input_statistics(mean, std)
        model = model.to(device)
        optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
        history: list[dict[str, Any]] = []
        start = 0
        if folder.resumed is not None:
            folder.restore(model, optimizer)
            history, start = list(folder.resumed.history), folder.resumed.epoch
            precision.restore(folder.resumed.extra)
        trained = torch.nn.parallel.DistributedDataParallel(model) if world > 1 else model
        reference = baseline(config.val_cache) if validating and config.val_cache is not None else {}
        dis_thr = (config.alpha + config.beta) / 2
        if history and "val_dis_thr" in history[-1]:
            dis_thr = history[-1]["val_dis_thr"]
            if not is_finite_number(dis_thr):  # validation always chooses one: an edit
                raise DataFormatError(folder.checkpoint_path, f"expected a finite number, got {dis_thr!r}",
                                      field=f"history[{len(history) - 1}].val_dis_thr")
        progress.start(max(0, config.epochs - start), "epoch", "train siamese")
        epochs_run = []
        for epoch in range(start, config.epochs):
            began = time.perf_counter()
            lr = step_decay(config.lr, config.lr_decay, config.lr_step, epoch)
            set_learning_rate(optimizer, lr)
            row: dict[str, Any] = {"epoch": epoch + 1, "lr": lr,
                                   **train_epoch(trained, optimizer, config, device, precision, epoch, rank, world)}
            check_losses_finite(row)
            if validating:
                row |= validate(model, config, device) | reference
                dis_thr = row["val_dis_thr"]
            row["seconds"] = time.perf_counter() - began
            history.append(row)
            folder.save(Checkpoint(kind=KIND, config=resolved, epoch=epoch + 1, model=model.state_dict(),
                                   optimizer=optimizer.state_dict(), history=history,
                                   extra={"dis_thr": dis_thr, "feature_shape": list(feature_shape),
                                          "baseline": reference, **precision.checkpoint_extra()}),
                        curves=epoch + 1 == config.epochs)
            epochs_run.append(epoch + 1)
            if on_epoch is not None and rank == 0:
                on_epoch(row)
            progress.advance()
    finish_distributed(world)
    return SiameseResult(out=Path(out), epochs_run=epochs_run, resumed_from=start,
                         metrics=history[-1] if history else {}, baseline=reference, dis_thr=dis_thr,
                         parameters=parameter_count(model), history=history, precision=precision.name)


# --------------------------------------------------------------------------- inference


def load_encoder(run: str | Path, device: str | torch.device = "cpu") -> tuple[SiameseEncoder, float]:
    """The trained encoder of a siamese run, in eval mode on ``device``, and its matching threshold.

    Args:
        run: a run folder of `sianms train siamese` (its ``checkpoint.pt`` is read) or the
            checkpoint file itself.
        device: where the model goes ("cpu", "cuda", "cuda:N", "auto" or a torch.device).

    Returns:
        (encoder, dis_thr): the encoder carries its input standardisation (buffers of the
        checkpoint), so :func:`embed` needs nothing else; ``dis_thr`` is the distance above
        which a cross-camera pair is dismissed, chosen on the run's validation cache (the
        margins' midpoint (α + β) / 2 for a run trained without one).

    Raises:
        DataFormatError naming the file: missing, not a sianms checkpoint (pickled object,
        foreign or missing keys), another model's checkpoint, weights that do not fit the
        config it stores, or no ``dis_thr``. The file is read with ``weights_only=True``.
    """
    path = checkpoint_file(run)
    return encoder_from_checkpoint(load_checkpoint(path, kind=KIND), path, device)


def encoder_from_checkpoint(checkpoint: Checkpoint, path: Path,
                            device: str | torch.device = "cpu") -> tuple[SiameseEncoder, float]:
    """:func:`load_encoder` for a checkpoint already read from ``path`` (named in errors)."""
    config = checkpoint.config if isinstance(checkpoint.config, dict) else {}
    shape = checkpoint.extra.get("feature_shape", config.get("feature_shape")) if isinstance(
        checkpoint.extra, dict) else None
    missing = [key for key in ("dim", "conv_channels", "hidden") if key not in config]
    if missing or not (isinstance(shape, (list, tuple)) and len(shape) == 3):
        raise DataFormatError(path, f"the stored config lacks {missing or ['feature_shape']}: not a siamese run's "
                              "checkpoint", field="config")
    dis_thr = checkpoint.extra.get("dis_thr")
    if not (isinstance(dis_thr, (int, float)) and not isinstance(dis_thr, bool) and math.isfinite(dis_thr)
            and dis_thr > 0):
        raise DataFormatError(path, f"no finite matching threshold > 0 (got {dis_thr!r})", field="extra.dis_thr")
    try:
        channels, height, width = (int(v) for v in shape)  # three: checked above
        model = build_model(config, (channels, height, width))
    except (TypeError, ValueError, RuntimeError) as error:  # torch refuses a negative width with a RuntimeError
        raise DataFormatError(path, f"the stored config does not describe an encoder ({error})",
                              field="config") from None
    state = dict(checkpoint.model)
    if not config.get("standardize") and not {"input_mean", "input_std"} & set(state):
        # a run from before the optional standardisation: its inputs were the raw features
        state |= {"input_mean": model.input_mean.clone(), "input_std": model.input_std.clone()}
    load_state(model, state, path)
    target = choose_device(device) if isinstance(device, str) else device
    return model.to(target).eval(), float(dis_thr)


@torch.no_grad()
def embed(model: SiameseEncoder, features: np.ndarray, batch: int = 256) -> np.ndarray:
    """Embeddings of ROI features: (N, C, PH, PW) float16/float32 -> (N, d) float32 (on the CPU).

    Runs the model in eval mode on its own device, ``batch`` rows per forward pass, without
    gradients; the rows are independent (no batch statistics), so ``batch`` changes the result
    by floating-point rounding at most. N = 0 gives a (0, d) array. A shape other than the model's (C, PH, PW) is
    a SianmsError.
    """
    features = np.asarray(features)
    if features.ndim != 4 or tuple(features.shape[1:]) != tuple(model.feature_shape):
        raise SianmsError(f"ROI features of shape {tuple(features.shape)} do not fit this encoder, which takes "
                          f"(N, {', '.join(map(str, model.feature_shape))}): same backbone and --roi-size as "
                          "its training cache?")
    if batch < 1:
        raise SianmsError(f"embed batch must be at least 1, got {batch}")
    model.eval()
    device = next(model.parameters()).device
    parts = [model(_tensor(features[start:start + batch], device)).float().cpu().numpy()
             for start in range(0, len(features), batch)]
    return np.concatenate(parts) if parts else np.zeros((0, model.dim), dtype=np.float32)


# --------------------------------------------------------------------------- the paper's ablation over d


SWEEP_COLUMNS = ("dim", "parameters", "val_auc", "val_f1", "val_dis_thr", "baseline_auc", "baseline_f1", "seconds")


def parse_dims(text: str) -> tuple[int, ...]:
    """'5,10,20' -> (5, 10, 20): positive, distinct; a malformed list names ``--sweep-dims``."""
    try:
        dims = tuple(int(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise SianmsError(f"--sweep-dims must be comma-separated integers, got '{text}'") from None
    if not dims or min(dims) < 1 or len(set(dims)) != len(dims):
        raise SianmsError(f"--sweep-dims must list distinct positive sizes, got '{text}'")
    return dims


def sweep(config: SiameseConfig, dims: tuple[int, ...], out: str | Path, *, overwrite: bool = False,
          resume: bool = False, progress: Progress = SILENT,
          on_epoch: Callable[[dict[str, Any]], None] | None = None) -> list[dict[str, Any]]:
    """Train one model per embedding size (paper §IV-C: d = 5 … 1000) into ``out/d<d>/``.

    Each is an ordinary run folder (resumable on its own); ``out/sweep.json`` and
    ``out/sweep.md`` tabulate d, parameters, the last epoch's validation AUC and matching F1,
    and the wall time, and are rewritten after each d so an interrupted sweep keeps its rows.
    ``out`` must be new, empty or a sweep's (:func:`check_sweep_folder`).
    """
    check_sweep_folder(Path(out), overwrite=overwrite, resume=resume)
    out = make_folder(out)
    rows = []
    for dim in dims:
        began = time.perf_counter()
        result = run(replace(config, dim=dim), out / f"d{dim}", overwrite=overwrite, resume=resume,
                     progress=progress, on_epoch=on_epoch)
        metrics = result.metrics
        figures = {key: metrics.get(key) for key in SWEEP_COLUMNS if key.startswith(("val_", "baseline_"))}
        rows.append({"dim": dim, "parameters": result.parameters, "seconds": time.perf_counter() - began,
                     **{key: None if isinstance(v, float) and math.isnan(v) else v for key, v in figures.items()}})
        if writes_outputs():  # under torchrun the other ranks' rows lack the validation rank 0 ran
            write_json(out / "sweep.json", {"config": config.resolved(), "rows": rows})
            write_text(out / "sweep.md", sweep_markdown(rows))
    return rows


SWEEP_FILES = ("sweep.json", "sweep.md")
_SWEEP_RUN = re.compile(r"d[0-9]+")


def check_sweep_folder(out: Path, *, overwrite: bool, resume: bool) -> None:
    """Refuse an ``out`` that is not a sweep's to write: one holding anything but a sweep's tables
    (:data:`SWEEP_FILES`, a killed write's temporaries of them) and its runs' ``d<d>/`` folders
    (each checked by its run as it starts), tables without a sweep.json of a sweep, or an
    earlier sweep without ``resume`` or ``overwrite``: its tables are rewritten."""
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out} exists and is not a folder; choose another --out")
    if not out.is_dir():
        return
    for entry in sorted(out.iterdir()):
        own = (_SWEEP_RUN.fullmatch(entry.name) is not None if entry.is_dir()
               else (partial_of(entry.name) or entry.name) in SWEEP_FILES)
        if entry.is_symlink() or not own:
            raise OutputExistsError(f"{out} holds {entry.name}, which a sianms sweep does not write; "
                                    "choose another --out")
    tables = [name for name in SWEEP_FILES if (out / name).exists()]
    if tables and not _is_sweep_record(out / "sweep.json"):
        raise OutputExistsError(f"{out / tables[0]} is not a sianms sweep's (no sweep.json of one); "
                                "choose another --out")
    if tables and not (overwrite or resume):
        raise OutputExistsError(f"{out} holds a sweep; pass --resume to continue it or --overwrite to replace it")


def _is_sweep_record(path: Path) -> bool:
    if not path.is_file():
        return False
    try:
        record = read_json(path)
    except DataFormatError:
        return False
    return isinstance(record, dict) and isinstance(record.get("config"), dict) and isinstance(record.get("rows"), list)


def sweep_markdown(rows: list[dict[str, Any]]) -> str:
    """The sweep as a markdown table, one row per d."""
    def cell(value: Any) -> str:
        if value is None or (isinstance(value, float) and math.isnan(value)):
            return "n/a"
        return f"{value:,}" if isinstance(value, int) else f"{value:.3f}"

    lines = ["| " + " | ".join(SWEEP_COLUMNS) + " |", "|" + "---|" * len(SWEEP_COLUMNS)]
    lines += ["| " + " | ".join(cell(row.get(key)) for key in SWEEP_COLUMNS) + " |" for row in rows]
    return "\n".join(lines) + "\n"
