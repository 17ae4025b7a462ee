"""Frustum-level figures of a Frustum PointNets on a held-out cache, as the training's validation
computes them (per class: 3-D IoU >= 0.5 and >= 0.7 rates, centre error, heading error as the AOE
counts it and modulo π, heading-bin accuracy, segmentation accuracy), for a zoo entry's model card.

The 2-D boxes are the cache's (detections associated with ground truth, or projected ground truth),
so these figures measure the 3-D stage alone; `sianms eval` and `sianms metrics` score the boxes a
whole pipeline reports.

Usage: python scripts/zoo_held_out.py --fpointnet RUN|zoo:NAME --cache HELD_OUT_CACHE --out FIGURES.json
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
import torch

from sianms_cli.io import write_json
from sianms_cli.evaluation.inference import FPointNetPredictor
from sianms_cli.training.fpointnet import FPointNetConfig, validate
from sianms_cli.training.run import checkpoint_file, load_checkpoint


def held_out_figures(fpointnet: str, cache: str, seed: int = 0) -> dict[str, float]:
    path = checkpoint_file(fpointnet)
    checkpoint = load_checkpoint(path, "fpointnet")
    predictor = FPointNetPredictor(checkpoint, path)
    fields = {key: value for key, value in checkpoint.config.items() if key in FPointNetConfig.__dataclass_fields__}
    config = replace(FPointNetConfig(**{**fields, "cache": cache}), val_cache=cache, init=None)
    rng = np.random.default_rng(seed)
    generator = torch.Generator().manual_seed(seed)
    return validate(predictor.model, config, rng, generator, torch.device("cpu"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fpointnet", required=True)
    parser.add_argument("--cache", required=True)
    parser.add_argument("--out", required=True)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    figures = held_out_figures(args.fpointnet, args.cache, args.seed)
    write_json(args.out, {"fpointnet": args.fpointnet, "cache": args.cache, "seed": args.seed,
                          "figures": by_class(figures)})
    for group, values in by_class(figures).items():
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
