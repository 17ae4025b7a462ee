"""How a Frustum PointNets boxes a car from the union of two cameras' frustums, against each camera's half
alone: the paper's premise, measured on an evaluation's own boxes.

For every true cross-camera match of an evaluation (the oracle's merged boxes, cars), the union box and
the two single-camera boxes of the same two detections are each matched to the nearest ground-truth car
of the sample within 2 m of its centre in bird's-eye view, as the nuScenes detection metrics match a box
(no range or point-count filter). Where all three reach the same car (in every evaluation given), the
script compares their centre errors (metres, bird's-eye view, as ATE) and heading errors (radians,
period 2π, as AOE): means over the pairs, the share where the union's centre error is below both
halves', and the share of boxes turned by more than π/2. Several evaluations of one world (a study's
arms) must hold the same true matches, as the oracle's are whatever the detector, and are scored on
the same pairs.

The ground truth is read from ``--dataroot``: the world itself, or the same world's tables alone
(`sianms synth ... --sensors none` with the world's arguments gives the same annotations and sample
tokens in a few minutes where the world was pruned); every evaluation's samples must be in its
``--split``.

Usage: python scripts/union_box_errors.py --dataroot DATA --version v1.0-trainval --split val EVAL [EVAL ...]
       [--out FIGURES.json]
       python scripts/union_box_errors.py --summarize FIGURES.json [FIGURES.json ...]

``--summarize`` reads one such file per world and prints, as Markdown, each evaluation folder name's figures as
mean ± sample standard deviation over the worlds and, for two folder names (a study's two arms), the second
minus the first world by world with its 95 % Student-t interval.
"""

from __future__ import annotations

import argparse
import json
import sys
from functools import reduce
from pathlib import Path

import numpy as np

from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.evaluation.finish import read_boxes
from sianms_cli.evaluation.methods import AllBoxes
from sianms_cli.geometry.quaternion import quat_yaw
from sianms_cli.io import describe_os_error, read_json, write_json
from sianms_cli.metrics.algo import yaw_diff
from sianms_cli.metrics.boxes import LABEL
from sianms_cli.metrics.dataset import eval_split, ground_truth
from sianms_cli.nuscenes.loader import NuScenesDB

MATCH_DISTANCE = 2.0
"""Metres in bird's-eye view: the nuScenes metrics' matching distance for ATE and AOE."""
TURNED = np.pi / 2
"""A heading error above this turns the box closer to front-to-back than to the truth."""


def nearest_truth(sample: np.ndarray, xy: np.ndarray, truth_sample: np.ndarray, truth_xy: np.ndarray) -> np.ndarray:
    """For each box (its sample index and (x, y)), the index of the nearest ground-truth box of the same sample
    within :data:`MATCH_DISTANCE`, or -1."""
    order = np.argsort(truth_sample, kind="stable")
    samples = max(int(sample.max(initial=-1)), int(truth_sample.max(initial=-1))) + 1
    counts = np.bincount(truth_sample, minlength=samples)
    starts = np.concatenate([[0], np.cumsum(counts)])[:-1]
    width = int(counts.max(initial=0))
    if len(sample) == 0 or width == 0:
        return np.full(len(sample), -1, dtype=np.int64)
    slot = starts[sample][:, None] + np.arange(width)  # (B, width) positions in ``order``
    present = np.arange(width) < counts[sample][:, None]
    candidates = order[np.where(present, slot, 0)]
    distance = np.linalg.norm(truth_xy[candidates] - xy[:, None, :], axis=2)
    distance[~present] = np.inf
    best = distance.argmin(axis=1)
    nearest = candidates[np.arange(len(sample)), best]
    return np.where(distance[np.arange(len(sample)), best] <= MATCH_DISTANCE, nearest, -1)


def union_rows(boxes: AllBoxes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(union, half a, half b): row indices of each true match's car box and of its two detections' single-camera
    boxes."""
    unions = np.flatnonzero((boxes.kind == "oracle") & (boxes.classes == "car") & ~boxes.dismissed)
    singles = np.flatnonzero(boxes.kind == "single")
    by_id = singles[np.argsort(boxes.detection_a[singles], kind="stable")]
    ids = boxes.detection_a[by_id]

    def single_of(detections: np.ndarray) -> np.ndarray:
        position = np.searchsorted(ids, detections)
        found = (position < len(ids)) & (ids[np.minimum(position, len(ids) - 1)] == detections)
        if not found.all():
            raise SianmsError(f"a match's detection {detections[~found][0][:40]!r} has no single-camera box")
        return by_id[position]
    return unions, single_of(boxes.detection_a[unions]), single_of(boxes.detection_b[unions])


def scored_pairs(boxes: AllBoxes, truth_sample: np.ndarray, truth_xy: np.ndarray) -> dict[str, np.ndarray]:
    """An evaluation's true matches: ``rows`` (3, P) of the union and its halves, ``truth`` (3, P) the ground-truth
    car each reached (-1: none within 2 m), ``same`` (P,) whether all three reached the same one, and ``keys`` (P,)
    the match (sample and the two detection ids) for comparing evaluations."""
    union, half_a, half_b = union_rows(boxes)
    rows = np.stack([union, half_a, half_b])
    truth = nearest_truth(boxes.sample[rows.ravel()], boxes.translation[rows.ravel(), :2], truth_sample,
                          truth_xy).reshape(rows.shape)
    keys = np.char.add(np.char.add(np.char.add(boxes.sample[union].astype(str), " "), boxes.detection_a[union]),
                       np.char.add(" ", boxes.detection_b[union]))
    return {"rows": rows, "truth": truth, "same": (truth[0] >= 0) & (truth == truth[0]).all(axis=0), "keys": keys}


def pair_figures(boxes: AllBoxes, rows: np.ndarray, truth: np.ndarray, truth_xy: np.ndarray,
                 truth_yaw: np.ndarray) -> dict[str, float | None]:
    """Centre and heading errors of the unions (``rows[0]``) and their halves against ``truth`` (module docstring)."""
    centre = np.linalg.norm(boxes.translation[rows, :2] - truth_xy[truth], axis=2)  # (3, P)
    heading = yaw_diff(truth_yaw[truth], boxes.yaw[rows])

    def mean(values: np.ndarray) -> float | None:
        return float(values.mean()) if values.size else None
    return {"union_centre_error": mean(centre[0]), "halves_centre_error": mean(centre[1:]),
            "better_half_centre_error": mean(centre[1:].min(axis=0)),
            "union_below_both_halves": mean(centre[0] < centre[1:].min(axis=0)),
            "union_heading_error": mean(heading[0]), "halves_heading_error": mean(heading[1:]),
            "union_turned": mean(heading[0] > TURNED), "halves_turned": mean(heading[1:] > TURNED)}


def evaluation_config(path: Path) -> dict:
    """An evaluation's config from its eval.json, refused unless it names the detector and seed."""
    marker = read_json(path)
    config = marker.get("config") if isinstance(marker, dict) else None
    for field, kind in (("fpointnet_sha256", str), ("seed", int)):
        if not (isinstance(config, dict) and isinstance(config.get(field), kind)):
            raise DataFormatError(path, f"must hold the evaluation's config with its {kind.__name__} {field}",
                                  field=f"config.{field}")
    return config


def figures(dataroot: str, version: str, split: str, evals: list[str]) -> list[dict]:
    """Each evaluation's figures, with its folder and detector fingerprint."""
    db = NuScenesDB(dataroot, version)
    samples = eval_split(db, split)
    truth, _ = ground_truth(db, samples)
    truth = truth[truth["label"] == LABEL["car"]]
    truth_sample, truth_xy = truth["sample"].astype(np.int64), truth["translation"][:, :2]
    truth_yaw = quat_yaw(truth["rotation"])
    read = []
    for folder in map(Path, evals):
        scenes = sorted((folder / "scenes").glob("*.parquet"))
        if not scenes:
            raise DataFormatError(folder / "scenes", "holds no scene's boxes; is this a `sianms eval` folder?")
        config = evaluation_config(folder / "eval.json")
        boxes = read_boxes(scenes, list(samples.sample_tokens))
        read.append((folder, config, boxes, scored_pairs(boxes, truth_sample, truth_xy)))
    keys = read[0][3]["keys"]
    for folder, _, _, pairs in read[1:]:
        if not np.array_equal(np.sort(pairs["keys"]), np.sort(keys)):
            raise SianmsError(f"{folder}: its true matches are not {read[0][0]}'s; evaluations are compared on one "
                              "world's matches")
    # The pairs every evaluation scored, so that the evaluations are compared on the same cars.
    scored = reduce(np.intersect1d, [pairs["keys"][pairs["same"]] for *_, pairs in read])
    out = []
    for folder, config, boxes, pairs in read:
        kept = np.isin(pairs["keys"], scored)
        out.append({"eval": str(folder), "fpointnet_sha256": config["fpointnet_sha256"], "seed": config["seed"],
                    "matches": int(len(keys)), "scored": int(kept.sum()),
                    **pair_figures(boxes, pairs["rows"][:, kept], pairs["truth"][:, kept], truth_xy, truth_yaw)})
    return out


FIGURES = ("union_centre_error", "halves_centre_error", "better_half_centre_error", "union_below_both_halves",
           "union_heading_error", "halves_heading_error", "union_turned", "halves_turned")


def summary(worlds: list[list[dict]]) -> str:
    """The Markdown table of ``--summarize`` over the worlds' figures (one list per world)."""
    from sianms_cli.reporting.runs_report import spread

    arms: dict[str, dict[int, dict]] = {}
    for world in worlds:
        for entry in world:
            arms.setdefault(Path(entry["eval"]).name, {})[entry["seed"]] = entry
    names = list(arms)
    seeds = sorted(set.intersection(*(set(by_seed) for by_seed in arms.values())))
    lines = [f"{len(seeds)} worlds (seeds {', '.join(map(str, seeds))}); pairs scored per world: "
             + ", ".join(str(arms[names[0]][seed]["scored"]) for seed in seeds), "",
             "| evaluation | " + " | ".join(figure.replace("_", " ") for figure in FIGURES) + " |",
             "|" + "---|" * (len(FIGURES) + 1)]
    for name in names:
        cells = [spread([arms[name][seed][figure] for seed in seeds]) for figure in FIGURES]
        lines.append(f"| {name} | " + " | ".join(f"{c['mean']:.3f} ± {c['sd']:.3f}" for c in cells) + " |")
    if len(names) == 2:
        first, second = arms[names[0]], arms[names[1]]
        cells = [spread([second[seed][figure] - first[seed][figure] for seed in seeds]) for figure in FIGURES]
        lines.append(f"| {names[1]} − {names[0]} | " + " | ".join(
            f"{c['mean']:+.3f} ± {c['sd']:.3f} [{c['ci95'][0]:+.3f}, {c['ci95'][1]:+.3f}]" for c in cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataroot", help="the world, or its tables alone")
    parser.add_argument("--version")
    parser.add_argument("--split", help="the split the evaluations scored")
    parser.add_argument("--out", type=Path, help="write the figures here as JSON (else printed)")
    parser.add_argument("--summarize", nargs="+", type=Path, help="figures files, one per world: print their summary")
    parser.add_argument("evals", nargs="*", help="`sianms eval` folders of that split")
    args = parser.parse_args()
    try:
        if args.summarize:
            sys.stdout.write(summary([read_json(path) for path in args.summarize]))
            return
        if not (args.dataroot and args.version and args.split and args.evals):
            raise SianmsError("--dataroot, --version, --split and at least one EVAL are needed (or --summarize)")
        result = figures(args.dataroot, args.version, args.split, args.evals)
        if args.out is None:
            print(json.dumps(result, indent=2))
        else:
            write_json(args.out, result)
    except (SianmsError, OSError) as error:
        text = describe_os_error(error) if isinstance(error, OSError) else str(error)
        print(f"error: {text}", file=sys.stderr)
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()
