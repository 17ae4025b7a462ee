"""Benchmark of distributed training on this machine's CPUs: 2 gloo processes against one process.

Both trainings run the same two data streams (`--streams 2`), so they train the same batches:
- one process with 2 torch threads (`sianms train ... --streams 2 --threads 2`);
- `torchrun --nproc-per-node 2`, one thread each, each rank reading only its stream's shards.
Prints, measured in the same run, siamese pairs per second and F-PointNets training frustums per
second over the epochs after the first (metrics.csv's timings: no start-up, no validation), the
2-process / 1-process ratio, and the shard bytes each rank reads in the siamese training's first
epoch against the cache's (the reading is split, not repeated).

Usage: python bench/train_ddp.py [--scenes 4] [--seconds 20] [--image-scale 0.25] [--epochs 3] [--keep DIR]
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from sianms_cli.data.siamese import shard_paths
from sianms_cli.data.streams import deal_shards, rank_streams
from sianms_cli.training.run import epoch_generator
from train import make_cache

FPOINTNET = ["--num-points", "256", "--num-object-points", "128", "--batch-size", "32", "--min-box-height", "0"]


def train(model: str, cache: Path, out: Path, epochs: int, processes: int) -> list[dict[str, str]]:
    """metrics.csv's rows of one training with 2 streams on ``processes`` processes (2 threads in all)."""
    command = ["train", model, "--cache", str(cache), "--out", str(out), "--epochs", str(epochs), "--streams", "2",
               "--device", "cpu", "--quiet", *(FPOINTNET if model == "fpointnet" else [])]
    if processes == 1:
        launch = [sys.executable, "-m", "sianms_cli", *command, "--threads", "2"]
    else:
        launch = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", str(processes),
                  "-m", "sianms_cli", *command, "--threads", "1"]
    subprocess.run(launch, check=True, capture_output=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    with open(out / "metrics.csv", newline="") as stream:
        return list(csv.DictReader(stream))


def rate(model: str, rows: list[dict[str, str]]) -> float:
    """Pairs (siamese: a positive and a hard negative per reference) or frustums per second after epoch 1."""
    steady = rows[1:] or rows
    if model == "siamese":
        return sum(2 * int(row["train_references"]) for row in steady) / sum(float(row["seconds"]) for row in steady)
    return sum(int(row["train_count"]) for row in steady) / sum(float(row["train_seconds"]) for row in steady)


def bytes_read(cache: Path) -> tuple[list[int], int]:
    """(bytes of the detections and pairs shards each of 2 ranks reads in the siamese training's
    epoch 1 at seed 0, the same for the whole cache)."""
    paths = shard_paths(cache)
    sizes = np.array([sum((cache / folder / path.name).stat().st_size for folder in ("detections", "pairs"))
                      for path in paths])
    dealt = deal_shards([path.stat().st_size for path in paths], epoch_generator(0, 0), 2)  # the epoch's first draw
    per_rank = [int(sizes[np.concatenate([dealt[s] for s in rank_streams(2, rank, 2)])].sum()) for rank in range(2)]
    return per_rank, int(sizes.sum())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=4)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--image-scale", type=float, default=0.25)
    parser.add_argument("--epochs", type=int, default=3)
    parser.add_argument("--keep", type=Path, default=None, help="Folder to keep the dataset, cache and runs in.")
    args = parser.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="sianms-bench-ddp-"))
    cache = make_cache(work, args.scenes, args.seconds, args.image_scale)
    print(f"{args.scenes} scenes x {args.seconds:g} s, {args.epochs} epochs, 2 streams; rates over epochs 2+")
    print("model     | unit       | 1 process x 2 threads | 2 processes x 1 thread | ratio")
    for model, unit in (("siamese", "pairs/s"), ("fpointnet", "frustums/s")):
        one = rate(model, train(model, cache, work / f"{model}-one", args.epochs, 1))
        two = rate(model, train(model, cache, work / f"{model}-two", args.epochs, 2))
        print(f"{model:9s} | {unit:10s} | {one:21.1f} | {two:22.1f} | {two / one:.2f}")
    per_rank, total = bytes_read(cache)
    print(f"siamese epoch 1, shard bytes read: rank 0 {per_rank[0] / 1e6:.1f} MB, rank 1 {per_rank[1] / 1e6:.1f} MB, "
          f"the cache {total / 1e6:.1f} MB (what each rank read before streams)")


if __name__ == "__main__":
    main()
