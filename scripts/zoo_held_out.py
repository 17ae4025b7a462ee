"""Frustum-level figures of a Frustum PointNets on a held-out cache, as the training's validation
computes them (per class: 3-D IoU >= 0.5 and >= 0.7 rates, centre error, heading error as the AOE
counts it and modulo π, heading-bin accuracy, segmentation accuracy) and how the heading errs
(within 30° of the truth, turned front to back within 30° of π, or off the axis), overall and by
the box's range from the camera, for a zoo entry's model card. ``--devkit`` adds the official
devkit's per-class figures from scripts/devkit_dump.py's output (AP in %, ATE, ASE, AOE,
ground-truth boxes).

The 2-D boxes are the cache's (detections associated with ground truth, or projected ground truth),
so these figures measure the 3-D stage alone; `sianms eval` and `sianms metrics` score the boxes a
whole pipeline reports.

Usage: python scripts/zoo_held_out.py --fpointnet RUN|zoo:NAME --cache HELD_OUT_CACHE --out FIGURES.json
                                      [--devkit DEVKIT_DUMP.json]
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace

import numpy as np
import torch

from sianms_cli.io import write_json
from sianms_cli.evaluation.inference import FPointNetPredictor
from sianms_cli.training.fpointnet import FPointNetConfig, validation_figures, validation_rows
from sianms_cli.training.run import checkpoint_file, load_checkpoint


DEVKIT_CLASSES = ("car", "pedestrian", "bicycle")
TURN = np.pi / 6
"""A heading within this of the truth is right; within this of the truth turned by π, flipped."""
RANGES = ((0.0, 15.0), (15.0, 30.0), (30.0, np.inf))
"""Bands of the box centre's range from the camera (m) the heading outcomes are also split by."""


def held_out_figures(fpointnet: str, cache: str, seed: int = 0) -> dict[str, dict[str, float]]:
    """The validation figures of ``fpointnet`` on ``cache``, by class, with each class's heading outcomes."""
    path = checkpoint_file(fpointnet)
    checkpoint = load_checkpoint(path, "fpointnet")
    model = FPointNetPredictor(checkpoint, path).model
    fields = {key: value for key, value in checkpoint.config.items() if key in FPointNetConfig.__dataclass_fields__}
    config = replace(FPointNetConfig(**{**fields, "cache": cache}), val_cache=cache, init=None)

    rows = validation_rows(model, config, np.random.default_rng(seed), torch.Generator().manual_seed(seed),
                           torch.device("cpu"))
    grouped = by_class(validation_figures(rows, config.classes))
    for k, name in enumerate(config.classes):
        grouped[f"{name}, frustums"].update(heading_outcomes(rows["heading"][rows["class"] == k]))
        for near, far in RANGES:
            keep = (rows["class"] == k) & (rows["range"] >= near) & (rows["range"] < far)
            band = f"{near:.0f}-{far:.0f} m" if np.isfinite(far) else f">= {near:.0f} m"
            if keep.any():
                grouped[f"{name}, frustums at {band}"] = {"count": int(keep.sum()),
                                                         **heading_outcomes(rows["heading"][keep])}
    return grouped


def heading_outcomes(errors: np.ndarray) -> dict[str, float]:
    """Shares of heading ``errors`` (radians, in [0, π]) that are right, flipped front to back, or off the axis."""
    if not len(errors):
        return {}
    right, flipped = errors < TURN, errors > np.pi - TURN
    return {"heading_right": round(float(right.mean()), 4), "heading_flipped": round(float(flipped.mean()), 4),
            "heading_off_axis": round(float((~right & ~flipped).mean()), 4)}


def devkit_figures(path: str) -> dict[str, dict[str, float]]:
    """Per class of :data:`DEVKIT_CLASSES`: AP (%, mean over the distance thresholds) and the true-positive
    errors, from the official devkit's evaluation as scripts/devkit_dump.py writes it."""
    with open(path, encoding="utf-8") as file:
        evaluation = json.load(file)["evaluation"]
    return {f"{name}, devkit": {"AP": round(100 * evaluation["mean_dist_aps"][name], 1),
                                "ATE": round(evaluation["label_tp_errors"][name]["trans_err"], 3),
                                "ASE": round(evaluation["label_tp_errors"][name]["scale_err"], 3),
                                "AOE": round(evaluation["label_tp_errors"][name]["orient_err"], 3),
                                "ground_truth": evaluation["gt_boxes_per_class"][name]}
            for name in DEVKIT_CLASSES}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fpointnet", required=True)
    parser.add_argument("--cache", required=True)
    parser.add_argument("--out", required=True)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--devkit", help="scripts/devkit_dump.py's output on the held-out world's results")
    args = parser.parse_args()
    figures = held_out_figures(args.fpointnet, args.cache, args.seed)
    if args.devkit:
        figures.update(devkit_figures(args.devkit))
    write_json(args.out, {"fpointnet": args.fpointnet, "cache": args.cache, "seed": args.seed, "figures": figures})
    for group, values in figures.items():
        print(f"{group}: " + ", ".join(f"{key} {value:.3f}" for key, value in values.items()))


def by_class(figures: dict[str, float]) -> dict[str, dict[str, float]]:
    """``val_car_iou_0.7`` -> ``{"car, frustums": {"iou_0.7": ...}}`` (``val_iou_0.7`` under "all, frustums")."""
    grouped: dict[str, dict[str, float]] = {}
    classes = {key[len("val_"):-len("_count")] for key in figures if key.endswith("_count") and key != "val_count"}
    for key, value in figures.items():
        name = key[len("val_"):]
        owner = next((c for c in classes if name.startswith(f"{c}_")), None)
        metric = name[len(owner) + 1:] if owner else name
        grouped.setdefault(f"{owner or 'all'}, frustums", {})[metric] = (int(value) if metric == "count"
                                                                          else round(float(value), 4))
    return grouped


if __name__ == "__main__":
    main()
