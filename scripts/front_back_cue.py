"""How well a car's LiDAR points tell its front from its back when everything else is known: a reference
for the heading direction a Frustum PointNets can learn on a dataset (docs/model_zoo.md#entries).

Each car frustum's ground-truth object points (segmentation label 1) are put in its ground-truth box's
frame (origin at the centre, x along the length, y down, z along the width; docs/methods.md#box-corners),
scaled by the box's length, height and width, and turned by π for a random half of the cars. A small
PointNet (shared layers 64-128-256, max pool, 128, 1) learns on one cache to tell which cars were turned,
and is scored on another: the share of held-out cars it gets right, overall and by the range of the box
centre from the camera. A mirror left to right, which keeps front and back, augments the training.

A detector must also find the centre, the axis, the size and the object points, so the share of cars on
the right axis it turns the right way round is expected below this one; the gap is what its recipe leaves.
Frustums with no object point carry no cue and are counted apart.

Usage: python scripts/front_back_cue.py --train-cache CACHE --held-out-cache CACHE --out FIGURES.json
                                        [--epochs 30] [--points 128] [--min-box-height 6.25] [--seed 0]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
import torch
from torch import nn

from sianms_cli.data.frustum_dataset import FrustumSelection, ShardFrustums, frustum_shards, read_shard
from sianms_cli.errors import SianmsError
from sianms_cli.io import describe_os_error, write_json

RANGES = ((0.0, 15.0), (15.0, 30.0), (30.0, np.inf))
"""Bands of the box centre's range from the camera (m), as scripts/zoo_held_out.py splits heading outcomes."""
CLASSES = ("car", "pedestrian", "bicycle")
BATCH = 64


def box_frame_points(shard: ShardFrustums, num_points: int, rng: np.random.Generator
                     ) -> tuple[np.ndarray, np.ndarray, int]:
    """The shard's car frustums with object points: (points (F, N, 4) in the box frame scaled by the box's
    size, with intensity; range (F,) of the box centre from the camera) and how many car frustums had none."""
    frustum = np.repeat(np.arange(len(shard)), np.diff(shard.offsets))
    keep = (shard.labels == 1) & (shard.class_index[frustum] == 0)
    counts = np.bincount(frustum[keep], minlength=len(shard))
    cars = np.flatnonzero(shard.class_index == 0)
    with_points = cars[counts[cars] > 0]
    object_points, owner = shard.points[keep], frustum[keep]
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])[with_points]
    index = starts[:, None] + np.floor(rng.random((len(with_points), num_points))
                                       * counts[with_points][:, None]).astype(np.int64)
    chosen, of = object_points[index], owner[index]
    offset = chosen[..., :3] - shard.center[of]
    cos, sin = np.cos(shard.heading[of]), np.sin(shard.heading[of])
    length, width, height = (shard.lwh[of, k] for k in range(3))
    along = (cos * offset[..., 0] - sin * offset[..., 2]) / length
    across = (sin * offset[..., 0] + cos * offset[..., 2]) / width
    points = np.stack([along, offset[..., 1] / height, across, chosen[..., 3]], axis=-1).astype(np.float32)
    ranges = np.hypot(shard.center[with_points, 0], shard.center[with_points, 2])
    return points, ranges, len(cars) - len(with_points)


def car_set(cache: str, num_points: int, min_box_height: float, rng: np.random.Generator
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Every car of ``cache`` with object points: (points, turned (F,) 0/1, range) and the count without points."""
    selection = FrustumSelection(classes=CLASSES, num_points=num_points, min_box_height=min_box_height)
    parts = [box_frame_points(read_shard(path, selection), num_points, rng) for path in frustum_shards(cache)]
    points = np.concatenate([part[0] for part in parts])
    turned = rng.integers(0, 2, len(points))
    points[turned == 1, :, 0] *= -1  # a turn by π about the vertical axis: along and across change sign
    points[turned == 1, :, 2] *= -1
    return points, turned, np.concatenate([part[1] for part in parts]), sum(part[2] for part in parts)


class TurnClassifier(nn.Module):
    """A PointNet (shared per-point layers, max pool) giving the logit that a car was turned by π."""

    def __init__(self) -> None:
        super().__init__()
        self.per_point = nn.Sequential(
            nn.Conv1d(4, 64, 1), nn.BatchNorm1d(64), nn.ReLU(), nn.Conv1d(64, 128, 1), nn.BatchNorm1d(128),
            nn.ReLU(), nn.Conv1d(128, 256, 1), nn.BatchNorm1d(256), nn.ReLU())
        self.head = nn.Sequential(nn.Linear(256, 128), nn.ReLU(), nn.Dropout(0.3), nn.Linear(128, 1))

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        return self.head(self.per_point(points.transpose(1, 2)).amax(dim=2))[:, 0]


def train_epoch(model: TurnClassifier, optimiser: torch.optim.Optimizer, points: torch.Tensor,
                turned: torch.Tensor, generator: torch.Generator) -> float:
    """One pass over the training cars in a random order; the mean loss."""
    model.train()
    order, losses = torch.randperm(len(points), generator=generator), []
    for start in range(0, len(order) - 1, BATCH):  # a last batch of one would break batch norm
        rows = order[start:start + BATCH]
        batch = points[rows].clone()
        mirror = torch.rand(len(rows), generator=generator) < 0.5
        batch[mirror, :, 2] *= -1
        loss = nn.functional.binary_cross_entropy_with_logits(model(batch), turned[rows])
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        losses.append(loss.item())
    return float(np.mean(losses))


def right_by_range(model: TurnClassifier, points: torch.Tensor, turned: np.ndarray, ranges: np.ndarray
                   ) -> dict[str, float]:
    """The share of cars whose turn ``model`` gets right, overall and by range band."""
    model.eval()
    with torch.no_grad():
        logits = torch.cat([model(points[start:start + 1024]) for start in range(0, len(points), 1024)])
    right = (logits.numpy() > 0) == (turned == 1)
    shares = {"all": float(right.mean())}
    for near, far in RANGES:
        band = (ranges >= near) & (ranges < far)
        name = f"{near:.0f}-{far:.0f} m" if np.isfinite(far) else f">= {near:.0f} m"
        shares[name] = float(right[band].mean()) if band.any() else float("nan")
    return shares


def cue_figures(train_cache: str, held_out_cache: str, epochs: int, num_points: int, min_box_height: float,
                seed: int) -> dict:
    """Train the classifier on ``train_cache``'s cars and score it on ``held_out_cache``'s, every epoch."""
    rng, generator = np.random.default_rng(seed), torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    train_points, train_turned, _, _ = car_set(train_cache, num_points, min_box_height, rng)
    test_points, test_turned, test_ranges, no_points = car_set(held_out_cache, num_points, min_box_height, rng)
    model = TurnClassifier()
    optimiser = torch.optim.Adam(model.parameters(), lr=1e-3)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, epochs)
    train_x, train_y = torch.from_numpy(train_points), torch.from_numpy(train_turned).float()
    test_x = torch.from_numpy(test_points)
    curve = []
    for epoch in range(1, epochs + 1):
        loss = train_epoch(model, optimiser, train_x, train_y, generator)
        schedule.step()
        curve.append({"epoch": epoch, "loss": loss, **right_by_range(model, test_x, test_turned, test_ranges)})
        print(f"epoch {epoch}: loss {loss:.3f}, held-out cars turned the right way {curve[-1]['all']:.3f}",
              file=sys.stderr, flush=True)
    return {"train_cars": len(train_points), "held_out_cars": len(test_points),
            "held_out_cars_without_object_points": no_points, "epochs": epochs, "points": num_points,
            "seed": seed, "right": curve[-1], "curve": curve}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train-cache", required=True)
    parser.add_argument("--held-out-cache", required=True)
    parser.add_argument("--out", required=True)
    parser.add_argument("--epochs", type=int, default=30)
    parser.add_argument("--points", type=int, default=128)
    parser.add_argument("--min-box-height", type=float, default=6.25)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    try:
        write_json(args.out, cue_figures(args.train_cache, args.held_out_cache, args.epochs, args.points,
                                         args.min_box_height, args.seed))
    except (SianmsError, OSError) as error:
        print(f"error: {describe_os_error(error) if isinstance(error, OSError) else error}", file=sys.stderr)
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()
