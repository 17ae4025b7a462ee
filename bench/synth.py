"""Benchmark `sianms synth`: samples per second and peak memory.

Runs the generator in a fresh child process per measurement (so peak RSS is the run's
own) and prints, next to the absolute figures, two ratios measured in the same run:

- time per sample against the *I/O floor*: encoding and writing the same number of JPEG
  images and LiDAR files of the same sizes, which any generator of this dataset pays;
- peak memory of a run with twice the scenes against the run itself, which must stay
  near 1.0 because scenes are streamed to disk.

    python bench/synth.py                       # v1.0-mini, 10 scenes, image scale 0.5
    python bench/synth.py --scenes 2 --workers 2
"""

from __future__ import annotations

import argparse
import multiprocessing
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

from sianms_cli.nuscenes.sensors import write_jpeg, write_pcd_bin
from sianms_cli.synth.generate import SynthConfig, run as run_synth
from sianms_cli.nuscenes.tables import CAMERA_CHANNELS
from sianms_cli.synth.rig import FULL_IMAGE_SIZE


def _synth_child(out: str, config: SynthConfig, workers: int, queue) -> None:
    start = time.perf_counter()
    run_synth(config, Path(out), workers=workers)
    seconds = time.perf_counter() - start
    peak_kib = max(resource.getrusage(who).ru_maxrss for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
    queue.put((seconds, peak_kib / 1024))


def measure_synth(config: SynthConfig, workers: int) -> tuple[float, float]:
    """(seconds, peak RSS in MiB of the busiest process: the run or one of its workers)."""
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    with tempfile.TemporaryDirectory() as folder:
        process = context.Process(target=_synth_child, args=(f"{folder}/data", config, workers, queue))
        process.start()
        seconds, peak = queue.get()
        process.join()
    return seconds, peak


def measure_io_floor(samples: int, image_scale: float) -> float:
    """Seconds to encode and write ``samples`` keyframes' worth of files (6 JPEGs, one sweep)."""
    rng = np.random.default_rng(0)
    width, height = round(FULL_IMAGE_SIZE[0] * image_scale), round(FULL_IMAGE_SIZE[1] * image_scale)
    image = (rng.random((height, width, 3)) * 40 + 90).astype(np.uint8)  # mid-grey with texture
    points = rng.normal(0.0, 10.0, (30_000, 5)).astype(np.float32)
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        for k in range(samples):
            for channel in CAMERA_CHANNELS:
                write_jpeg(Path(folder) / f"{channel}_{k}.jpg", image)
            write_pcd_bin(Path(folder) / f"lidar_{k}.pcd.bin", points)
        return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=10)
    parser.add_argument("--image-scale", type=float, default=0.5)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--memory-scene-seconds", type=float, default=4.0,
                        help="scene length of the two runs that compare peak memory")
    args = parser.parse_args()

    config = SynthConfig(scenes=args.scenes, image_scale=args.image_scale)
    samples = args.scenes * config.keyframes
    seconds, peak = measure_synth(config, args.workers)
    floor = measure_io_floor(samples, args.image_scale)
    print(f"synth v1.0-mini: {args.scenes} scenes, {samples} samples, image scale {args.image_scale}, "
          f"{args.workers} worker(s)")
    print(f"  {seconds:.1f} s, {samples / seconds:.2f} samples/s, peak RSS {peak:.0f} MiB")
    print(f"  I/O floor (JPEG + pcd.bin writes of the same sizes): {floor:.1f} s "
          f"-> synth / floor = {seconds / floor:.1f}x")

    small = SynthConfig(scenes=2, image_scale=args.image_scale, scene_seconds=args.memory_scene_seconds)
    large = SynthConfig(scenes=8, image_scale=args.image_scale, scene_seconds=args.memory_scene_seconds)
    _, peak_small = measure_synth(small, 1)
    _, peak_large = measure_synth(large, 1)
    print(f"  peak RSS with 2 scenes {peak_small:.0f} MiB, with 8 scenes {peak_large:.0f} MiB "
          f"-> ratio {peak_large / peak_small:.2f} (flat in the number of scenes: ~1.0)")


if __name__ == "__main__":
    main()
