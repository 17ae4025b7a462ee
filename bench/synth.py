"""Benchmark `sianms synth`: samples per second and peak memory.

Runs the generator in a fresh child process per measurement (so peak RSS is the run's
own) and prints, next to the absolute figures, two ratios measured in the same run:

- time per sample against the *I/O floor*: encoding and writing the same number of JPEG
  images and LiDAR files (key frame and the 9 sweeps before it) of the same sizes, which
  any generator of this dataset pays;
- the LiDAR ray casting of one sweep (raster cull + pair test of lidar.py) against the
  general bundle-culled caster (raycast.intersect_parts) on the same rays and parts of a
  generated scene, with the same hits: the speed-up that lets synth cast ten sweeps per
  key frame;
- peak memory of a run with twice the scenes against the run itself, which must stay
  near 1.0 because scenes are streamed to disk;
- with ``--reference-tree DIR`` (a checkout of another commit, e.g. from ``git worktree add``),
  the wall time of ``sianms synth`` from that tree against this one, each run by the command
  line in a fresh process, one after the other, same flags (``--rounds N``: N such pairs and
  the median of their ratios): what a speed target set against an earlier version ("within
  1.5x of ...") is read from.

    python bench/synth.py                       # v1.0-mini, 10 scenes, image scale 0.5
    python bench/synth.py --scenes 2 --workers 2
    git worktree add ../sianms-ref 7307555 && \
        python bench/synth.py --image-scale 0.25 --workers 2 --reference-tree ../sianms-ref --only-reference --rounds 3
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sianms_cli.nuscenes.sensors import write_jpeg, write_pcd_bin
from sianms_cli.nuscenes.tables import CAMERA_CHANNELS
from sianms_cli.synth import generate, lidar
from sianms_cli.synth.generate import AZIMUTH_STEPS, SWEEPS_BETWEEN_KEYFRAMES, SynthConfig, run as run_synth
from sianms_cli.synth.raycast import intersect_ground, intersect_parts
from sianms_cli.synth.nuscenes_rig import FULL_IMAGE_SIZE, RIG_BOSTON, normalised_rig
from sianms_cli.synth.world import plan_scene


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


def measure_cli(tree: Path, scenes: int, image_scale: float, workers: int, seed: int) -> float:
    """Wall seconds of ``sianms synth`` run from the source tree ``tree`` in a fresh process.

    The process starts in an empty folder: ``python -m`` puts its working folder first on the
    path, so from a checkout it would import that checkout's code whatever PYTHONPATH says.
    """
    env = {**os.environ, "PYTHONPATH": str(tree.resolve())}
    with tempfile.TemporaryDirectory() as folder:
        imported = subprocess.run([sys.executable, "-c", "import sianms_cli; print(sianms_cli.__file__)"], env=env,
                                  cwd=folder, check=True, capture_output=True, text=True).stdout.strip()
        if not Path(imported).resolve().is_relative_to(tree.resolve()):
            raise SystemExit(f"{tree}: sianms_cli imports from {imported}, not from this tree")
        command = [sys.executable, "-m", "sianms_cli", "synth", "--out", f"{folder}/data", "--scenes", str(scenes),
                   "--image-scale", str(image_scale), "--workers", str(workers), "--seed", str(seed), "--quiet"]
        start = time.perf_counter()
        subprocess.run(command, env=env, cwd=folder, check=True, stdout=subprocess.DEVNULL)
        return time.perf_counter() - start


def compare_with_reference(reference: Path, scenes: int, image_scale: float, workers: int, rounds: int) -> None:
    """Print this tree's synth time against the reference tree's, measured one after the other,
    ``rounds`` times; with several, the median of the rounds' ratios (a shared machine's speed
    drifts between minutes, so only the two runs of one round are compared with each other)."""
    here = Path(__file__).resolve().parents[1]
    seed = 2026
    print(f"sianms synth --scenes {scenes} --image-scale {image_scale} --workers {workers} --seed {seed}, "
          f"reference tree {reference}:")
    ratios = []
    for index in range(rounds):
        before = measure_cli(reference, scenes, image_scale, workers, seed)
        now = measure_cli(here, scenes, image_scale, workers, seed)
        ratios.append(now / before)
        print(f"  round {index + 1}: reference {before:.1f} s, this tree {now:.1f} s "
              f"-> {now / before:.2f}x the reference", flush=True)
    if rounds > 1:
        print(f"  median of {rounds} rounds: {np.median(ratios):.2f}x (range {min(ratios):.2f}-{max(ratios):.2f}x)")


def measure_io_floor(samples: int, image_scale: float) -> float:
    """Seconds to encode and write ``samples`` keyframes' worth of files (6 JPEGs, 10 sweeps)."""
    rng = np.random.default_rng(0)
    width, height = round(FULL_IMAGE_SIZE[0] * image_scale), round(FULL_IMAGE_SIZE[1] * image_scale)
    image = (rng.random((height, width, 3)) * 40 + 90).astype(np.uint8)  # mid-grey with texture
    points = rng.normal(0.0, 10.0, (AZIMUTH_STEPS * 32, 5)).astype(np.float32)
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        for k in range(samples):
            for channel in CAMERA_CHANNELS:
                write_jpeg(Path(folder) / f"{channel}_{k}.jpg", image)
            for j in range(SWEEPS_BETWEEN_KEYFRAMES + 1):
                write_pcd_bin(Path(folder) / f"lidar_{k}_{j}.pcd.bin", points)
        return time.perf_counter() - start


def scene_rays(seed: int = 0):
    """Rays (origin, directions), their ground hits and the parts of one key-frame sweep of a
    generated scene (a still sensor: both casters take the same rays)."""
    config = SynthConfig(scenes=1, seed=seed, scene_seconds=0.5)
    plan = plan_scene(generate._scene_rng(seed, 0, "plan"), 1)
    with tempfile.TemporaryDirectory() as folder:
        sensing = generate._SceneSensing(plan, normalised_rig(RIG_BOSTON), config, 0, Path(folder), "bench", 0)
    center, yaw, _ = plan.agents.pose(plan.route, 0.0)
    ego = sensing._ego_to_global(0.0)
    parts = sensing._parts_at(center, yaw, np.hypot(*(center[:, :2] - ego[:2, 3]).T) < generate.RENDER_RADIUS)
    pose = ego @ sensing.lidar_to_ego
    dirs_lidar, _ = lidar.beam_directions(AZIMUTH_STEPS, sensing.start_azimuth)
    dirs = dirs_lidar @ pose[:3, :3].T
    t_ground = intersect_ground(pose[:3, 3], dirs, t_max=100.0)
    return pose, sensing.start_azimuth, dirs, np.minimum(t_ground, 100.0), parts


def raster_cast(pose, start_azimuth, dirs, t_max, parts):
    """Nearest part hits of one sweep's rays by lidar.py's raster cull and pair test."""
    origins = np.zeros_like(dirs)
    level = lidar._level_frame(pose)
    inflate = np.full(len(parts), 1e-3)
    margins = lidar._direction_margins(dirs, level, start_azimuth, AZIMUTH_STEPS)
    ray, part = lidar.candidate_pairs(parts, pose[:3, 3], level, inflate, start_azimuth, AZIMUTH_STEPS, *margins)
    local = dataclasses.replace(parts, center=parts.center - pose[:3, 3])
    return lidar._nearest_hits(ray, part, origins, dirs, local, t_max.astype(np.float32), None)


def measure_lidar(repeats: int = 5) -> tuple[float, float, int]:
    """(seconds per sweep raster-culled, seconds bundle-culled, rays whose hit differs), best of ``repeats``."""
    pose, start_azimuth, dirs, t_max, parts = scene_rays()
    raster, bundle = [], []
    for _ in range(repeats):
        start = time.perf_counter()
        t_new, part_new, _ = raster_cast(pose, start_azimuth, dirs, t_max, parts)
        raster.append(time.perf_counter() - start)
        start = time.perf_counter()
        t_old, part_old, _, _ = intersect_parts(pose[:3, 3], dirs, parts, t_max=t_max, bundle=32)
        bundle.append(time.perf_counter() - start)
    differ = int(np.sum((part_new != part_old) | ~np.isclose(t_new, t_old, rtol=0, atol=1e-4)))
    return min(raster), min(bundle), differ


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=10)
    parser.add_argument("--image-scale", type=float, default=0.5)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--memory-scene-seconds", type=float, default=4.0,
                        help="scene length of the two runs that compare peak memory")
    parser.add_argument("--reference-tree", type=Path, help="a checkout of another commit to time synth against")
    parser.add_argument("--only-reference", action="store_true", help="only the comparison with --reference-tree")
    parser.add_argument("--rounds", type=int, default=1, help="rounds of the comparison with --reference-tree")
    args = parser.parse_args()
    if args.reference_tree is not None:
        compare_with_reference(args.reference_tree, args.scenes, args.image_scale, args.workers, args.rounds)
        if args.only_reference:
            return

    config = SynthConfig(scenes=args.scenes, image_scale=args.image_scale)
    samples = args.scenes * config.keyframes
    seconds, peak = measure_synth(config, args.workers)
    floor = measure_io_floor(samples, args.image_scale)
    print(f"synth v1.0-mini: {args.scenes} scenes, {samples} samples, image scale {args.image_scale}, "
          f"{args.workers} worker(s)")
    print(f"  {seconds:.1f} s, {samples / seconds:.2f} samples/s, peak RSS {peak:.0f} MiB")
    print(f"  I/O floor (JPEG + pcd.bin writes of the same sizes): {floor:.1f} s "
          f"-> synth / floor = {seconds / floor:.1f}x")

    raster, bundle, differ = measure_lidar()
    print(f"  LiDAR ray casting per sweep: raster cull {raster * 1e3:.0f} ms, bundle cull {bundle * 1e3:.0f} ms "
          f"-> {bundle / raster:.1f}x faster ({differ} of {AZIMUTH_STEPS * 32} rays hit differently)")

    small = SynthConfig(scenes=2, image_scale=args.image_scale, scene_seconds=args.memory_scene_seconds)
    large = SynthConfig(scenes=8, image_scale=args.image_scale, scene_seconds=args.memory_scene_seconds)
    _, peak_small = measure_synth(small, 1)
    _, peak_large = measure_synth(large, 1)
    print(f"  peak RSS with 2 scenes {peak_small:.0f} MiB, with 8 scenes {peak_large:.0f} MiB "
          f"-> ratio {peak_large / peak_small:.2f} (flat in the number of scenes: ~1.0)")


if __name__ == "__main__":
    main()
