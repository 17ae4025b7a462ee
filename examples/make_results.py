"""Write a nuScenes results file made from a split's ground truth, perfect or perturbed.

Without training anything (`sianms eval` writes results from trained models), this gives
a newcomer a results file for `sianms metrics` without writing Python, and shows what each
kind of error costs:

    python examples/make_results.py --dataroot D --split mini_val --out perfect.json
    python examples/make_results.py --dataroot D --split mini_val --out noisy.json \\
        --perturb translation=0.5,yaw=0.1,drop=0.2,false-positives=0.3 --seed 0
    sianms metrics --dataroot D --split mini_val --results noisy.json --region all,overlap

Perfect predictions are the split's ground-truth boxes of the 10 detection classes that
hold at least one LiDAR or radar point (the devkit drops ground truth without points, so a
prediction there would be a false positive), with their class and attribute, the devkit's
ground-truth velocity (0 where it has none: the devkit skips those in AVE anyway) and score 1.
Every sample of the split is listed, with [] when it has no box, as the devkit requires.

``--perturb`` takes comma-separated KEY=VALUE, applied in this order from one generator
seeded by ``--seed`` (same seed, byte-identical file):

- ``drop=P``: each box is left out with probability P (misses);
- ``translation=S``: N(0, S) metres added to the centre's x and y;
- ``yaw=S``: N(0, S) radians added to the heading;
- ``size=S``: width, length and height each multiplied by exp(N(0, S));
- ``velocity=S``: N(0, S) m/s added to vx and vy;
- ``false-positives=R``: round(R x boxes kept) extra boxes, each a copy of a kept box of the
  same sample moved 5 to 10 m in a random direction.

With ``--perturb`` the scores are no longer 1: U(0.3, 1) for boxes from the ground truth,
U(0, 0.7) for false positives, so the ranking mixes them as a real detector's does.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

from sianms_cli.kernels import use_avx2_kernels

use_avx2_kernels()  # before numpy loads: the same bytes as `sianms` writes on any AVX2 machine

import numpy as np  # noqa: E402

from sianms_cli.errors import SianmsError, check_seed
from sianms_cli.metrics.boxes import NO_ATTRIBUTE
from sianms_cli.metrics.dataset import eval_split, ground_truth
from sianms_cli.metrics.results import results_from_boxes, write_results
from sianms_cli.geometry.quaternion import quat_multiply, yaw_to_quat
from sianms_cli.io import check_outside_dataroot, describe_os_error
from sianms_cli.nuscenes.loader import NuScenesDB

PERTURBATIONS = ("drop", "translation", "yaw", "size", "velocity", "false-positives")
PERTURBATION_LIMITS = {"drop": 1.0, "translation": 100.0, "yaw": 2 * math.pi, "size": 3.0, "velocity": 100.0,
                       "false-positives": 100.0}
"""Upper bounds of the --perturb values: 100 m and 100 m/s of noise, a full turn, sizes scaled by
exp(N(0, 3)) (a factor of 8,000 at three sigma), 100 false positives per kept box. Past them a
value is a typo: sizes overflowed to inf and 1e12 false positives asked for 226 TiB."""
FALSE_POSITIVE_OFFSET_M = (5.0, 10.0)  # beyond the largest matching threshold (4 m) of their own box


def parse_perturbations(text: str | None) -> dict[str, float] | None:
    """``"translation=0.5,drop=0.2"`` as {name: value}; None when not perturbing.

    Raises SianmsError naming ``--perturb`` for an unknown key, or a value that is not a number
    in [0, :data:`PERTURBATION_LIMITS`].
    """
    if text is None:
        return None
    values = dict.fromkeys(PERTURBATIONS, 0.0)
    for item in filter(None, (part.strip() for part in text.split(","))):
        key, _, value = item.partition("=")
        key = key.strip()
        if key not in values:
            raise SianmsError(f"--perturb: unknown key '{key}'; expected KEY=VALUE with KEY one of "
                              f"{', '.join(PERTURBATIONS)}")
        try:
            number = float(value)
        except ValueError:
            raise SianmsError(f"--perturb: {key} needs a number, got '{value}'") from None
        if not 0 <= number <= PERTURBATION_LIMITS[key]:
            raise SianmsError(f"--perturb: {key} must be in [0, {PERTURBATION_LIMITS[key]:g}], got {number:g}")
        values[key] = number
    return values


def perfect_predictions(gt: np.ndarray) -> np.ndarray:
    """The ground-truth boxes a perfect detector reports: those with points, as predictions."""
    boxes = gt[gt["num_pts"] != 0].copy()
    boxes["score"] = 1.0
    boxes["num_pts"] = -1
    boxes["velocity"] = np.nan_to_num(boxes["velocity"])
    boxes["attribute"][boxes["attribute"] < NO_ATTRIBUTE] = NO_ATTRIBUTE  # an attribute outside the 8
    return boxes


def perturb(boxes: np.ndarray, amounts: dict[str, float], rng: np.random.Generator) -> np.ndarray:
    """``boxes`` with the module docstring's perturbations, rows grouped by sample as given."""
    boxes = boxes[rng.random(len(boxes)) >= amounts["drop"]].copy()
    count = len(boxes)
    boxes["translation"][:, :2] += rng.normal(0.0, amounts["translation"], (count, 2))
    boxes["rotation"] = quat_multiply(yaw_to_quat(rng.normal(0.0, amounts["yaw"], count)), boxes["rotation"])
    boxes["size"] *= np.exp(rng.normal(0.0, amounts["size"], (count, 3)))
    boxes["velocity"] += rng.normal(0.0, amounts["velocity"], (count, 2))
    boxes["score"] = rng.uniform(0.3, 1.0, count)
    false_positives = boxes[rng.integers(0, count, round(amounts["false-positives"] * count))] if count else boxes[:0]
    distance = rng.uniform(*FALSE_POSITIVE_OFFSET_M, len(false_positives))
    heading = rng.uniform(-np.pi, np.pi, len(false_positives))
    false_positives["translation"][:, 0] += distance * np.cos(heading)
    false_positives["translation"][:, 1] += distance * np.sin(heading)
    false_positives["score"] = rng.uniform(0.0, 0.7, len(false_positives))
    return np.concatenate([boxes, false_positives])


def make_results(dataroot: str | Path, version: str, split: str, out: str | Path,
                 perturbations: dict[str, float] | None = None, *, seed: int = 0, overwrite: bool = False) -> int:
    """Write the results file ``out``; returns the number of boxes written."""
    check_seed(seed)
    check_outside_dataroot(out, dataroot, "--out", "make_results.py")  # --overwrite would replace a table
    if str(out).endswith(("/", os.sep)):
        raise SianmsError(f"--out: {out} names a folder; give the results file's name")
    db = NuScenesDB(dataroot, version)
    the_split = eval_split(db, split)
    gt, _ = ground_truth(db, the_split)
    boxes = perfect_predictions(gt)
    if perturbations is not None:
        boxes = perturb(boxes, perturbations, np.random.default_rng(seed))
    write_results(out, results_from_boxes(the_split.sample_tokens, boxes), overwrite=overwrite)
    return len(boxes)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     epilog="See the module docstring for what each perturbation does.")
    parser.add_argument("--dataroot", required=True, help="nuScenes-format dataroot")
    parser.add_argument("--version", default="v1.0-mini", help="version folder inside the dataroot")
    parser.add_argument("--split", required=True, help="predefined split or a name from <version>/splits.json")
    parser.add_argument("--out", required=True, help="results JSON to write")
    parser.add_argument("--perturb", metavar="KEY=VALUE,...",
                        help=f"keys: {', '.join(PERTURBATIONS)}; e.g. translation=0.5,drop=0.2")
    parser.add_argument("--seed", type=int, default=0, help="seed of the perturbations")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    args = parser.parse_args(argv)
    try:
        count = make_results(args.dataroot, args.version, args.split, args.out, parse_perturbations(args.perturb),
                             seed=args.seed, overwrite=args.overwrite)
    except SianmsError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except OSError as error:
        print(f"error: {describe_os_error(error)}", file=sys.stderr)
        return 2
    print(f"wrote {count} boxes to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
