"""How far apart the two detections of siaNMS's kept matches lie, right matches against wrong ones.

    python scripts/match_geometry.py sianms-demo-s0 sianms-demo-s1 ...

For each `sianms demo` folder (its dataset, and its evaluation's per-scene boxes tables), the
kept siaNMS matches (the frustum test's dismissals left out) split by ground-truth identity:
how many there are, the share whose two single-camera boxes overlap in bird's-eye view (what
``gated-sianms`` keeps), and the distance between those boxes' centres (median, 10th and
90th percentiles).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from sianms_cli.errors import SianmsError
from sianms_cli.io import describe_os_error, read_json
from sianms_cli.evaluation.methods import SIANMS, AllBoxes, gate_passed, match_singles


def match_geometry(boxes: AllBoxes) -> dict[str, dict[str, float]]:
    """{"right" | "wrong": {count, overlapping, median_m, p10_m, p90_m}} of the kept siaNMS matches
    whose two detections both have single-camera boxes."""
    rows = np.flatnonzero((boxes.kind == SIANMS) & ~boxes.dismissed)
    a, b = match_singles(boxes, rows)
    both = (a >= 0) & (b >= 0)
    rows, a, b = rows[both], a[both], b[both]
    overlapping = gate_passed(boxes, rows)
    distance = np.hypot(*(boxes.translation[a, :2] - boxes.translation[b, :2]).T)
    out = {}
    for name, mine in (("right", boxes.correct[rows]), ("wrong", ~boxes.correct[rows])):
        d = distance[mine]
        out[name] = {"count": int(mine.sum()), "overlapping": float(overlapping[mine].mean()) if mine.any() else None,
                     **{key: float(np.percentile(d, q)) if mine.any() else None
                        for key, q in (("median_m", 50), ("p10_m", 10), ("p90_m", 90))}}
    return out


def demo_boxes(folder: Path) -> AllBoxes:
    """The boxes of a `sianms demo` folder's evaluation."""
    from sianms_cli.metrics.dataset import eval_split
    from sianms_cli.nuscenes.loader import NuScenesDB
    from sianms_cli.evaluation.finish import read_boxes

    demo, evaluation = read_json(folder / "demo.json"), read_json(folder / "eval" / "eval.json")
    if not (isinstance(demo, dict) and demo.get("complete") and isinstance(evaluation, dict)
            and evaluation.get("complete")):
        raise SianmsError(f"{folder}: not a finished `sianms demo` (its demo.json and eval/eval.json say complete)")
    config, version = evaluation["config"], demo["config"]["version"]
    split = eval_split(NuScenesDB(str(folder / "data"), version), config["split"])
    return read_boxes([folder / "eval" / "scenes" / f"{name}.parquet" for name in config["split_scenes"]],
                      list(split.sample_tokens))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("demos", nargs="+", type=Path, help="`sianms demo` output folders")
    for folder in parser.parse_args().demos:
        try:
            figures = match_geometry(demo_boxes(folder))
        except (SianmsError, OSError) as error:
            print(f"error: {describe_os_error(error) if isinstance(error, OSError) else error}", file=sys.stderr)
            raise SystemExit(2) from None
        for name, f in figures.items():
            if f["count"]:
                print(f"{folder.name}: {f['count']} {name} matches, single-camera boxes overlapping in BEV "
                      f"{100 * f['overlapping']:.0f} %, centres {f['median_m']:.2f} m apart (median; p10 "
                      f"{f['p10_m']:.2f}, p90 {f['p90_m']:.2f})")
            else:
                print(f"{folder.name}: 0 {name} matches")


if __name__ == "__main__":
    main()
