"""Benchmark the BEV NMS variants of `sianms eval` against shapely, on one thread.

Workload (seeded): cars of 1.9 x 4.6 m, each size ±10 % (uniform), over a 100 x 100 m area,
each car detected 1 + Poisson(2) times with N(0, 0.3 m) centre and N(0, 0.1 rad) yaw jitter,
uniform scores, one class, 500 / 2,000 / 10,000 boxes in all, IoU threshold 0.3 (circle NMS:
CenterPoint's car radius, 2.0 m). Measured in the same run:

- ours: ``axis_nms`` in each of the three axis-aligned modes, ``rotated_nms``, ``circle_nms``;
- shapely 2: greedy NMS over polygons, with an STRtree for the candidates and vectorised
  intersections per kept box; its kept boxes are checked to equal ``rotated_nms``'s;
- numpy clipping: :func:`sianms_cli.geometry.bev.rotated_iou_pairs` on just the candidate
  pairs (centre distance <= half-diagonal sum), a lower bound for an NMS without numba;
- a fresh process: importing ``sianms_cli.evaluation.nms`` and its first call, which loads
  numba's cached machine code.

Each timing is the fastest of its repeats (the machine may be busy). Prints a table in ms and
the ratios rotated/axis and shapely/rotated; exits 1 if shapely keeps other boxes.

    python bench/nms.py
    python bench/nms.py --sizes 500 2000 --repeat 11
"""

from __future__ import annotations

import os

# One thread for every library, before numpy and numba start their pools.
for _variable in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_variable] = "1"

import argparse  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numba  # noqa: E402
import numpy as np  # noqa: E402
import shapely  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

from sianms_cli.geometry.bev import AXIS_MODES, bev_corners, rotated_iou_pairs  # noqa: E402
from sianms_cli.evaluation.nms import CIRCLE_RADIUS_M, axis_nms, circle_nms, rotated_nms  # noqa: E402

CAR_SIZE = (1.9, 4.6)  # (width, length), metres
AREA = 100.0
IOU_THRESHOLD = 0.3
FIRST_CALL = """
import time
start = time.perf_counter()
from sianms_cli.evaluation.nms import rotated_nms
imported = time.perf_counter()
import numpy as np
rotated_nms(np.zeros((2, 2)), np.ones((2, 2)), np.zeros(2), np.ones(2), np.zeros(2), 0.3)
print(imported - start, time.perf_counter() - imported)
"""


def workload(total: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(centers (N, 2), sizes (N, 2), yaw (N,), scores (N,)) of ``total`` detections of cars."""
    rng = np.random.default_rng(seed)
    cars = total // 3 + 16
    while True:  # enough cars for `total` detections (1 + Poisson(2) each, mean 3)
        copies = 1 + rng.poisson(2, cars)
        if copies.sum() >= total:
            break
        cars *= 2
    center = rng.uniform(0, AREA, (cars, 2))
    size = np.array(CAR_SIZE) * rng.uniform(0.9, 1.1, (cars, 2))
    yaw = rng.uniform(-np.pi, np.pi, cars)
    car = np.repeat(np.arange(cars), copies)[:total]
    return (center[car] + rng.normal(0, 0.3, (total, 2)), size[car], yaw[car] + rng.normal(0, 0.1, total),
            rng.uniform(0, 1, total))


def shapely_nms(centers, sizes, yaw, scores, threshold) -> np.ndarray:
    """Greedy rotated NMS over shapely polygons: STRtree candidates, vectorised intersections."""
    polygons = shapely.polygons(bev_corners(centers, sizes, yaw))
    areas = shapely.area(polygons)
    tree = shapely.STRtree(polygons)
    order = np.argsort(-scores, kind="stable")
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    suppressed = np.zeros(len(order), dtype=bool)
    kept = []
    for i in order:
        if suppressed[i]:
            continue
        kept.append(i)
        candidates = tree.query(polygons[i])
        candidates = candidates[(rank[candidates] > rank[i]) & ~suppressed[candidates]]
        intersection = shapely.area(shapely.intersection(polygons[i], polygons[candidates]))
        iou = intersection / np.maximum(areas[i] + areas[candidates] - intersection, 1e-8)
        suppressed[candidates[iou > threshold]] = True
    return np.array(kept, dtype=np.int64)


def numpy_candidate_iou(centers, sizes, yaw) -> int:
    """numpy rotated IoU of every candidate pair (centre distance <= half-diagonal sum); pairs."""
    half_diagonal = 0.5 * np.hypot(sizes[:, 0], sizes[:, 1])
    pairs = cKDTree(centers).query_pairs(2 * half_diagonal.max(), output_type="ndarray")
    first, second = pairs[:, 0], pairs[:, 1]
    near = np.linalg.norm(centers[first] - centers[second], axis=1) <= half_diagonal[first] + half_diagonal[second]
    boxes = np.column_stack([centers, sizes, yaw])
    rotated_iou_pairs(boxes[first[near]], boxes[second[near]])
    return int(near.sum())


def fastest(function, repeat: int) -> tuple[float, object]:
    """(fastest time in ms, result) of ``repeat`` calls."""
    best, result = np.inf, None
    for _ in range(repeat):
        start = time.perf_counter()
        result = function()
        best = min(best, time.perf_counter() - start)
    return best * 1e3, result


def first_call_seconds() -> tuple[float, float]:
    """(import seconds, first-call seconds) of rotated_nms in a fresh process."""
    output = subprocess.run([sys.executable, "-c", FIRST_CALL], check=True, capture_output=True, text=True,
                            env=os.environ).stdout.split()
    return float(output[0]), float(output[1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[500, 2000, 10000], help="boxes per workload")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=7, help="repeats of our NMS (fastest counts)")
    parser.add_argument("--reference-repeat", type=int, default=2, help="repeats of shapely and numpy clipping")
    args = parser.parse_args(argv)

    print(f"numpy {np.__version__}, numba {numba.__version__}, shapely {shapely.__version__}; one thread; "
          f"fastest of {args.repeat} (references: of {args.reference_repeat})")
    first_call_seconds()  # compiles into the cache, if this version has not been run yet
    imported, first = first_call_seconds()
    print(f"fresh process: import sianms_cli.evaluation.nms {imported:.2f} s, first rotated_nms call {first:.2f} s")
    print(f"ms per call; {', '.join(AXIS_MODES)} are axis_nms's modes; numpy-pairs is numpy clipping of the "
          f"candidate pairs alone")
    columns = ["boxes", "kept", *AXIS_MODES, "rotated", "circle", "shapely", "numpy-pairs"]
    print(" ".join(f"{column:>11}" for column in columns))
    failed = False
    for total in args.sizes:
        centers, sizes, yaw, scores = workload(total, args.seed)
        labels = np.zeros(total, dtype=np.int64)
        rotated_nms(centers, sizes, yaw, scores, labels, IOU_THRESHOLD)  # loads the compiled code
        times = {mode: fastest(lambda: axis_nms(centers, sizes, yaw, scores, labels, IOU_THRESHOLD, mode=mode),
                               args.repeat)[0] for mode in AXIS_MODES}
        times["rotated"], kept = fastest(lambda: rotated_nms(centers, sizes, yaw, scores, labels, IOU_THRESHOLD),
                                         args.repeat)
        times["circle"], _ = fastest(lambda: circle_nms(centers, scores, labels, CIRCLE_RADIUS_M["car"]), args.repeat)
        times["shapely"], reference = fastest(lambda: shapely_nms(centers, sizes, yaw, scores, IOU_THRESHOLD),
                                              args.reference_repeat)
        times["numpy-pairs"], pairs = fastest(lambda: numpy_candidate_iou(centers, sizes, yaw), args.reference_repeat)
        same = np.array_equal(kept, reference)
        failed |= not same
        cells = [f"{total:>11}", f"{len(kept):>11}"] + [f"{times[column]:>11.2f}" for column in columns[2:]]
        print(" ".join(cells))
        ratios = ", ".join(f"{mode} {times['rotated'] / times[mode]:.2f}x" for mode in AXIS_MODES)
        print(f"    rotated/axis: {ratios}; shapely/rotated {times['shapely'] / times['rotated']:.0f}x; "
              f"numpy clipping of the {pairs} candidate pairs alone / whole rotated NMS "
              f"{times['numpy-pairs'] / times['rotated']:.1f}x; shapely keeps "
              f"{'the same boxes' if same else f'OTHER boxes ({len(reference)})'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
