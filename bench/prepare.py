"""Benchmark of `sianms prepare` with the `tiny` backbone on this machine.

Prints, all measured in the same run:
- samples per second with 1 and 2 worker processes, and their ratio;
- peak resident memory of a whole `prepare` process on 1x and 4x the number of scenes, and
  their ratio (streaming writes: it should stay near 1);
- the simulated detector's recall and precision per class (IoU >= 0.5) against the
  calibration targets of docs/prepare.md.

Usage: python bench/prepare.py [--scenes 2] [--seconds 4] [--image-scale 0.25] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from sianms_cli.prepare.config import PrepareConfig
from sianms_cli.prepare.job import run as prepare
from sianms_cli.synth.generate import SynthConfig, run as run_synth

CHILD = """
import resource, sys, json
from sianms_cli.prepare.config import PrepareConfig
from sianms_cli.prepare.job import run as prepare
config = PrepareConfig(sys.argv[1], "v1.0-mini", "all", seed=0, fill_missed=True)
result = prepare(config, sys.argv[2], workers=1)
print(json.dumps({"samples": result.manifest["counts"]["samples"],
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""

TARGETS = {"car": (0.80, 0.85), "pedestrian": (0.62, 0.80), "bicycle": (0.58, 0.75)}


def dataset(root: Path, scenes: int, seconds: float, scale: float) -> Path:
    run_synth(SynthConfig(scenes=scenes, image_scale=scale, scene_seconds=seconds, seed=1), root)
    names = SynthConfig(scenes=scenes).scene_names()
    (root / "v1.0-mini" / "splits.json").write_text(json.dumps({"all": names}))
    return root


def quality(cache: Path) -> None:
    table = pq.read_table(cache / "detections", columns=["class", "source", "score", "instance_token", "gt_distance",
                                                         "gt_occlusion", "gt_truncation"]).to_pydict()
    cls = np.array(table["class"])
    source = np.array(table["source"])
    score = np.array(table["score"])
    matched = np.array([t is not None for t in table["instance_token"]])
    distance = np.array([d if d is not None else np.nan for d in table["gt_distance"]])
    visible = np.array([(1 - (o or 0)) * (1 - (t or 0)) for o, t in zip(table["gt_occlusion"], table["gt_truncation"])])
    print("\nsimulated detector vs targets (IoU >= 0.5; GT = every projected box not fully occluded)")
    print(f"{'class':<11} {'GT':>5} {'recall@0.05':>11} {'recall@0.5':>10} {'target':>6} {'prec@0.5':>8} {'target':>6}"
          f"  recall@0.5 by distance 0-20/20-30/30-40/40-50 m (visibility>=0.4)")
    for name, (r_target, p_target) in TARGETS.items():
        mine = cls == name
        det = mine & (source == "detector")
        gt_total = int((mine & matched).sum())
        found_any = int((det & matched).sum())
        found = int((det & matched & (score >= 0.5)).sum())
        kept = int((det & (score >= 0.5)).sum())
        bands = []
        for lo, hi in ((0, 20), (20, 30), (30, 40), (40, 50)):
            band = mine & matched & (distance >= lo) & (distance < hi) & (visible >= 0.4)
            bands.append(f"{(band & det & (score >= 0.5)).sum() / max(band.sum(), 1):.2f}({band.sum()})")
        print(f"{name:<11} {gt_total:>5} {found_any / max(gt_total, 1):>11.2f} {found / max(gt_total, 1):>10.2f} "
              f"{r_target:>6.2f} {found / max(kept, 1):>8.2f} {p_target:>6.2f}  {' '.join(bands)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=2)
    parser.add_argument("--seconds", type=float, default=4.0)
    parser.add_argument("--image-scale", type=float, default=0.25)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        small = dataset(tmp / "small", args.scenes, args.seconds, args.image_scale)
        large = dataset(tmp / "large", 4 * args.scenes, args.seconds, args.image_scale)
        rates = {}
        for workers in (1, 2):
            config = PrepareConfig(str(large), "v1.0-mini", "all", seed=0, fill_missed=True)
            start = time.perf_counter()
            result = prepare(config, tmp / f"cache-w{workers}", workers=workers)
            elapsed = time.perf_counter() - start
            rates[workers] = result.manifest["counts"]["samples"] / elapsed
            print(f"workers={workers}: {result.manifest['counts']['samples']} samples in {elapsed:.1f} s "
                  f"= {rates[workers]:.2f} samples/s (includes loading the dataset and process start-up)")
        print(f"speed-up 2 workers / 1 worker: {rates[2] / rates[1]:.2f}x")
        peaks = {}
        for label, root in (("1x", small), ("4x", large)):
            out = subprocess.run([sys.executable, "-c", CHILD, str(root), str(tmp / f"mem-{label}")],
                                 capture_output=True, text=True, check=True)
            peaks[label] = json.loads(out.stdout.strip().splitlines()[-1])
            print(f"{label} scenes ({peaks[label]['samples']} samples): peak RSS {peaks[label]['peak_rss_mb']:.0f} MB")
        print(f"peak memory 4x / 1x scenes: {peaks['4x']['peak_rss_mb'] / peaks['1x']['peak_rss_mb']:.2f}")
        quality(tmp / "cache-w1")


if __name__ == "__main__":
    main()
