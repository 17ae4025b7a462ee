"""Benchmark of `sianms train siamese` on this machine's CPU.

Prints, all measured in the same run, each in a fresh process:
- training pairs per second over the epochs after the first (one positive and one hard negative per
  reference; the negative candidates scored without gradients are counted apart) with 1
  and 2 torch threads, and their ratio;
- peak resident memory of one training epoch on a cache and on the same cache 4x (its shard
  files copied under other names), and their ratio (scene-by-scene streaming: near 1);
- with ``--precisions``, each other precision's pairs per second against fp32's on 2 threads;
- with ``--checks``, the cost of checking the cache against its manifest (every shard file's size,
  rows, SHA-256 and unique ids, once when the command starts): the whole run's seconds, start
  included, with the checks and with them switched off, on 1 thread, in turn, each pair five times.

``--device cuda`` trains on the GPU (the thread counts are then the CPU's, which read and pair
the batches).

Usage: python bench/train.py [--scenes 4] [--seconds 20] [--image-scale 0.25] [--epochs 4]
                             [--precisions fp32,bf16] [--device cpu|cuda|cuda:N] [--keep DIR] [--checks]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from sianms_cli.prepare.config import PrepareConfig
from sianms_cli.prepare.job import run as prepare
from sianms_cli.synth.generate import SynthConfig, run as run_synth

CHILD = """
import json, resource, sys, time
import torch
torch.set_num_threads(int(sys.argv[3]))
if sys.argv[7] == "off":  # the cache's manifest checks switched off (--checks), the listing still read
    from sianms_cli.data import cache
    cache.check_shard_file = cache.check_shard_size = lambda path, entry: None
    cache._refuse_unlisted = lambda root, listed: None
from sianms_cli.training.siamese import SiameseConfig, run
config = SiameseConfig(cache=sys.argv[1], epochs=int(sys.argv[4]), precision=sys.argv[5], device=sys.argv[6])
started = time.perf_counter()
result = run(config, sys.argv[2])
total = time.perf_counter() - started
# The epochs after the first only (all of them for a one-epoch run): the first carries torch's
# kernel selection and the page cache's first read; no start-up, no curves.png.
steady = result.history[1:] or result.history
seconds = sum(row["seconds"] for row in steady)
references = sum(row["train_references"] for row in steady)
candidates = sum(row["train_references"] * row["train_candidates_per_negative"] for row in steady)
print(json.dumps({"pairs_per_s": 2 * references / seconds, "candidates_per_s": candidates / seconds,
                  "references": references, "seconds": seconds, "total_seconds": total,
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def make_cache(root: Path, scenes: int, seconds: float, scale: float) -> Path:
    """A synthetic dataset of ``scenes`` scenes and its cache of every scene (split "all")."""
    data = run_synth(SynthConfig(scenes=scenes, image_scale=scale, scene_seconds=seconds, seed=1), root / "data").out
    (data / "v1.0-mini" / "splits.json").write_text(json.dumps({"all": SynthConfig(scenes=scenes).scene_names()}))
    return prepare(PrepareConfig(str(data), "v1.0-mini", "all", fill_missed=True), root / "cache").out


def copies(cache: Path, times: int, out: Path) -> Path:
    """The cache's detections and pairs shards ``times`` over, under distinct names, and its
    manifest listing them (training reads only a complete cache, and only the files its manifest lists)."""
    manifest = json.loads((cache / "manifest.json").read_text())
    files = {}
    for folder in ("detections", "pairs"):
        (out / folder).mkdir(parents=True)
        for path in sorted((cache / folder).glob("*.parquet")):
            for k in range(times):
                shutil.copyfile(path, out / folder / f"{path.stem}-{k}.parquet")
                files[f"{folder}/{path.stem}-{k}.parquet"] = manifest["files"][f"{folder}/{path.name}"]
    (out / "manifest.json").write_text(json.dumps({**manifest, "files": files}))
    return out


def child(cache: Path, out: Path, threads: int, epochs: int, precision: str = "fp32", device: str = "cpu",
          checks: str = "on") -> dict:
    done = subprocess.run([sys.executable, "-c", CHILD, str(cache), str(out), str(threads), str(epochs), precision,
                           device, checks], capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def measure_checks(cache: Path, work: Path, epochs: int, device: str) -> None:
    """Whole-run seconds (start included) with and without the manifest checks, alternated, five times each."""
    seconds: dict[str, list[float]] = {"on": [], "off": []}
    for attempt in range(5):
        for checks in ("on", "off"):
            figures = child(cache, work / f"run-checks-{checks}-{attempt}", 1, epochs, device=device, checks=checks)
            seconds[checks].append(figures["total_seconds"])
    best = {checks: min(values) for checks, values in seconds.items()}
    print(f"manifest checks: whole run {best['on']:.2f} s with, {best['off']:.2f} s without (best of 5 each); "
          f"with / without {best['on'] / best['off']:.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=4)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--image-scale", type=float, default=0.25)
    parser.add_argument("--epochs", type=int, default=4)
    parser.add_argument("--precisions", default="fp32", help="comma-separated, fp32 first: e.g. fp32,bf16")
    parser.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    parser.add_argument("--keep", type=Path, default=None, help="Folder to keep the dataset, caches and runs in.")
    parser.add_argument("--checks", action="store_true", help="Also time runs without the cache's manifest checks.")
    args = parser.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="sianms-bench-train-"))
    cache = make_cache(work, args.scenes, args.seconds, args.image_scale)
    manifest = json.loads((cache / "manifest.json").read_text())
    print(f"cache: {manifest['counts']['detections']} detections, {manifest['counts']['pairs']} pairs "
          f"({args.scenes} scenes x {args.seconds:g} s, images x{args.image_scale:g}); siamese defaults (d = 100)")
    rates = {threads: child(cache, work / f"run-t{threads}", threads, args.epochs, device=args.device)
             for threads in (1, 2)}
    for threads, figures in rates.items():
        print(f"{threads} thread(s): {figures['pairs_per_s']:.1f} pairs/s, {figures['candidates_per_s']:.1f} "
              f"negative candidates scored/s ({figures['references']} references in {figures['seconds']:.1f} s)")
    print(f"2 threads / 1 thread: {rates[2]['pairs_per_s'] / rates[1]['pairs_per_s']:.2f}x")
    for precision in args.precisions.split(",")[1:]:
        figures = child(cache, work / f"run-{precision}", 2, args.epochs, precision, args.device)
        print(f"{precision}, 2 threads: {figures['pairs_per_s']:.1f} pairs/s, "
              f"{figures['pairs_per_s'] / rates[2]['pairs_per_s']:.2f}x fp32's")
    if args.checks:
        measure_checks(cache, work, args.epochs, args.device)
    big = copies(cache, 4, work / "cache-4x")
    memory = {times: child(folder, work / f"run-{times}x", 1, 1)["peak_rss_mb"]
              for times, folder in ((1, cache), (4, big))}
    print(f"peak RSS, one epoch: 1x cache {memory[1]:.0f} MB, 4x cache {memory[4]:.0f} MB "
          f"(ratio {memory[4] / memory[1]:.2f})")
    if args.keep is None:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
