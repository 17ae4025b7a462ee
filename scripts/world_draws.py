"""The synthetic world's targets (docs/synthetic_world.md), over several draws of it.

    python scripts/world_draws.py INFO.json [INFO.json ...]

Each INFO.json is what ``sianms info --out`` wrote for one dataroot (one seed: one draw of the
world). One Markdown row per target: each draw's value, their mean and sample standard deviation,
real nuScenes (``sianms info``'s reference) and the target; the last column says whether the mean
meets it. A single set of 10 or 40 scenes swings with which of its scenes got roadworks or a busy
kerb; the mean over draws is what the world's parameters set.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from typing import Callable, NamedTuple

from sianms_cli.reporting.nuscenes_reference import REFERENCE


class Target(NamedTuple):
    figure: str
    read: Callable[[dict], float | None]  # None: the draw has no such figure (no LiDAR files)
    low: float
    high: float
    unit: str  # "%" for shares (printed times 100), "" otherwise
    real: str
    digits: int = 1


def _share(*path: str) -> Callable[[dict], float | None]:
    def read(info: dict) -> float | None:
        for key in path:
            info = info[key]
        return info
    return read


def _per_keyframe_targets() -> list[Target]:
    real = REFERENCE["objects_per_keyframe_by_class"].value
    return [Target(f"{name} per key frame", _share("objects_per_keyframe_by_class", name),
                   0.8 * real[name], 1.2 * real[name], "", f"{real[name]:.2f} (trainval)", 2)
            for name in ("car", "pedestrian", "barrier", "traffic_cone", "truck", "bicycle", "motorcycle", "bus")]


def _visibility_targets() -> list[Target]:
    real = REFERENCE["visibility_shares"].value
    return [Target(f"in-range visibility {name}", _share("class_range", "visibility_shares", name),
                   real[name] - 0.05, real[name] + 0.05, "%", f"{100 * real[name]:.1f} % (val)") for name in real]


def _points_per_sweep(info: dict) -> float | None:
    sweep = info["lidar_points_per_sweep"]
    return None if sweep is None else sweep["mean"]


TARGETS: list[Target] = [
    Target("image boxes per 3-D box", _share("image_boxes", "per_3d_box"), 1.18, 1.30, "", "1.215", 3),
    Target("… per human 3-D box", _share("image_boxes", "humans", "per_3d_box"), 1.13, float("inf"), "", "1.149", 3),
    Target("3-D boxes imaged by ≥ 2 cameras", _share("image_boxes", "share_imaged_by_2_or_more"), 0.20, 1.0, "%",
           "≥ 21.4 % (derived bound)"),
    Target("car centres in the overlap region (≤ 50 m, with points)",
           _share("car_share_in_overlap_within_50m_with_points"), 0.09, 1.0, "%", "≈ 11–13 % if uniform"),
    Target("cars within ±15° of the fore–aft axis",
           _share("car_azimuth_within_50m", "share_within_15deg_of_fore_aft_axis"), 0.25, 0.35, "%",
           "16.7 % if uniform"),
    Target("empty 15° azimuth bins within 50 m", _share("car_azimuth_within_50m", "empty_bins"), 0, 0, "", "—", 0),
    Target("cars heading within 5° of the ego's axes",
           _share("car_heading_to_axis_within_50m", "share_within_5deg_of_axis"), 0.0, 0.65, "%", "peaks at the axes"),
    *_per_keyframe_targets(),
    *_visibility_targets(),
    Target("annotations without a LiDAR point", _share("share_annotations_without_lidar_points"), 0.12, 0.19, "%",
           "18.7 % (mini)"),
    Target("LiDAR points per annotation", _share("lidar_points_per_annotation"), 45, 75, "", "58.8 (mini)"),
    Target("LiDAR points per sweep file", _points_per_sweep, 30_000, 38_000, "", "≈ 34,000", 0),
]


def _text(value: float, target: Target) -> str:
    return f"{value * (100 if target.unit == '%' else 1):,.{target.digits}f}"


def _bounds(target: Target) -> str:
    low, high, unit = _text(target.low, target), _text(target.high, target), f" {target.unit}" if target.unit else ""
    if target.high in (1.0, float("inf")) and target.low > 0:
        return f"≥ {low}{unit}"
    if target.low == target.high:
        return low
    if target.low == 0:
        return f"≤ {high}{unit}"
    return f"{low}–{high}{unit}"


def row(target: Target, infos: list[dict]) -> str:
    """The Markdown row of one target over the draws (draws without the figure print "—")."""
    values = [target.read(info) for info in infos]
    present = [value for value in values if value is not None]
    cells = [_text(value, target) if value is not None else "—" for value in values]
    if present:
        mean = statistics.fmean(present)
        spread = f" ± {_text(statistics.stdev(present), target)}" if len(present) > 1 else ""
        summary, verdict = f"{_text(mean, target)}{spread}", "yes" if target.low <= mean <= target.high else "no"
    else:
        summary, verdict = "—", "—"
    return " | ".join(["", target.figure, *cells, summary, target.real, _bounds(target), verdict, ""]).strip()


def table(infos: list[dict], names: list[str]) -> str:
    header = ["figure", *names, "mean ± sd", "real nuScenes", "target", "mean meets it"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + [row(target, infos) for target in TARGETS])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("infos", nargs="+", help="JSON files written by `sianms info --out`, one per draw")
    args = parser.parse_args(argv)
    infos = []
    for path in args.infos:
        with open(path, encoding="utf-8") as file:
            infos.append(json.load(file))
    print(table(infos, [f"seed {info['synth_marker']['config']['seed']}" if info.get("synth_marker") else path
                        for info, path in zip(infos, args.infos)]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
