"""Benchmark of `sianms eval`: per-sample latency of each stage, and samples per second end to end.

Runs the evaluation of a prepared split with trained runs (given, or made here: a synthetic
mini of --scenes scenes, its mini_train cache, one-epoch trainings) into a temporary
folder, one process, and prints from ``eval.json`` and the scenes' timings:

- per stage, milliseconds per sample: reading the cache, Frustum PointNets on the
  single-camera frustums, candidates, siamese embeddings, the assignment, union frustums,
  Frustum PointNets on the unions; then each method's selection (NMS, siaNMS, ...) with the
  networks excluded, its metrics, and the pictures;
- end-to-end samples per second of the scenes stage and of the whole evaluation;
- the share of the scenes stage spent in the networks, the reference the rest is measured
  against in the same run;
- with ``--checks``, the cost of the cache's checks (the folder against its manifest: every shard
  file's size, rows, SHA-256 and unique ids, once when the command starts; each scene's point
  lists): whole evaluations with the checks and with them switched off, in turn, five times each.

Usage: python bench/eval.py [--scenes 3] [--threads 1] [--device cuda] [--checks]
       python bench/eval.py --dataroot D --split S --cache C --siamese R1 --fpointnet R2

``--device cuda`` runs the evaluation's networks on the GPU (the inputs are made the same way).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import pyarrow.parquet as pq
import torch

from sianms_cli.data import cache as cache_module
from sianms_cli.evaluation import scene as scene_module
from sianms_cli.evaluation.job import EvalConfig, run
from sianms_cli.evaluation.scene import STAGES

NETWORK_STAGES = ("fpointnet_single", "embed", "fpointnet_union")


def make_inputs(folder: Path, scenes: int) -> dict[str, str]:
    """A synthetic mini, its mini_train cache and one-epoch trainings (what the tests use, larger)."""
    from sianms_cli.prepare.config import PrepareConfig
    from sianms_cli.prepare.job import run as prepare
    from sianms_cli.synth.generate import SynthConfig, run as synth
    from sianms_cli.training.fpointnet import FPointNetConfig, run as train_fpointnet
    from sianms_cli.training.siamese import SiameseConfig, run as train_siamese

    data = synth(SynthConfig(scenes=scenes, image_scale=0.25, scene_seconds=8.0, seed=7), folder / "data").out
    cache = prepare(PrepareConfig(dataroot=str(data), version="v1.0-mini", split="mini_train"), folder / "cache").out
    train_siamese(SiameseConfig(cache=str(cache), epochs=1), folder / "siamese")
    train_fpointnet(FPointNetConfig(cache=str(cache), epochs=1, num_points=512, batch_size=16, device="cpu"),
                    folder / "fpointnet")
    return {"dataroot": str(data), "split": "mini_train", "cache": str(cache), "siamese": str(folder / "siamese"),
            "fpointnet": str(folder / "fpointnet")}


def timed_evaluation(config: EvalConfig, out: Path, checks: bool) -> float:
    """Seconds of one whole evaluation into ``out``, the cache's checks on or switched off; what an
    earlier evaluation in this process checked is forgotten first (a command checks once, at its start)."""
    cache_module._CHECKED_CACHES.clear()
    cache_module._CHECKED_FILES.clear()
    switched = {(cache_module, "check_shard_file"): lambda path, entry: None,
                (cache_module, "check_shard_size"): lambda path, entry: None,
                (cache_module, "_refuse_unlisted"): lambda root, listed: None,
                (scene_module, "require_point_lists"): lambda path, table: None}
    saved = {key: getattr(*key) for key in switched}
    if not checks:
        for (module, name), replacement in switched.items():
            setattr(module, name, replacement)
    try:
        started = time.perf_counter()
        run(config, out)
        return time.perf_counter() - started
    finally:
        for (module, name), function in saved.items():
            setattr(module, name, function)


def measure_checks(config: EvalConfig, folder: Path) -> str:
    """Whole evaluations with and without the checks, alternated, five times each (after the main one, so
    none pays for the first compilation of the kernels)."""
    seconds: dict[bool, list[float]] = {True: [], False: []}
    for attempt in range(5):
        for checks in (True, False):
            seconds[checks].append(timed_evaluation(config, folder / f"eval-checks-{checks}-{attempt}", checks))
    best = {checks: min(values) for checks, values in seconds.items()}
    return (f"cache checks: whole evaluation {best[True]:.2f} s with, {best[False]:.2f} s without (best of 5 each); "
            f"with / without {best[True] / best[False]:.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=3, help="scenes of the generated mini (without --dataroot)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--device", default="cpu", help="torch device of the evaluation's networks (cpu, cuda, cuda:N)")
    for name in ("dataroot", "split", "cache", "siamese", "fpointnet"):
        parser.add_argument(f"--{name}")
    parser.add_argument("--version", default="v1.0-mini")
    parser.add_argument("--checks", action="store_true", help="also time evaluations without the cache's checks")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    with tempfile.TemporaryDirectory() as temporary:
        folder = Path(temporary)
        inputs = ({name: getattr(args, name) for name in ("dataroot", "split", "cache", "siamese", "fpointnet")}
                  if args.dataroot else make_inputs(folder, args.scenes))
        config = EvalConfig(version=args.version, device=args.device, **inputs)
        started = time.perf_counter()
        result = run(config, folder / "eval")
        total = time.perf_counter() - started
        stages = dict.fromkeys(STAGES, 0.0)
        samples = 0
        for path in sorted((folder / "eval" / "scenes").glob("*.parquet")):
            timings = json.loads(pq.read_schema(path).metadata[b"sianms.timings"])
            samples += timings["samples"]
            for stage in STAGES:
                stages[stage] += timings[stage]
        finish = result.manifest["timings"]
        checks = measure_checks(config, folder) if args.checks else None
    print(f"{samples} samples, device {args.device}, torch threads {args.threads}, {torch.__version__}")
    print(f"{'stage':<34}{'ms/sample':>12}")
    for stage, seconds in stages.items():
        print(f"{'scenes: ' + stage:<34}{1000 * seconds / samples:>12.1f}")
    for key, seconds in finish.items():
        if key != "scenes_s":
            print(f"{'finish: ' + key.removesuffix('_s'):<34}{1000 * seconds / samples:>12.2f}")
    networks = sum(stages[stage] for stage in NETWORK_STAGES)
    print(f"scenes stage: {samples / finish['scenes_s']:.2f} samples/s; networks {networks / sum(stages.values()):.0%} "
          f"of the stages' time, everything else {sum(stages.values()) - networks:.2f} s "
          f"({(sum(stages.values()) - networks) / networks:.2f}x the networks)")
    print(f"whole evaluation: {samples / total:.2f} samples/s ({total:.1f} s)")
    if checks is not None:
        print(checks)


if __name__ == "__main__":
    main()
