"""Figures that describe a nuScenes-format dataset, for `sianms info`.

The same figures are published for real nuScenes (``shared/reference/nuscenes.md`` §9),
so a synthetic dataroot can be compared with the real one line by line.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sianms_cli.errors import SianmsError
from sianms_cli.io import check_writable_output, write_json
from sianms_cli.progress import SILENT, Progress
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.overlap import box_overlap_pairs, centers_in_ego, lidar_ego_poses
from sianms_cli.nuscenes.tables import check_version_name

CAR = "vehicle.car"
CAR_EVAL_RANGE = 50.0  # the devkit's class range for cars (detection_cvpr_2019)
VISIBILITY_LEVELS = {"1": "v0-40", "2": "v40-60", "3": "v60-80", "4": "v80-100"}


@dataclass(frozen=True)
class InfoConfig:
    """What `sianms info` reads."""

    dataroot: str
    version: str = "v1.0-mini"
    max_sweeps: int = 200  # LiDAR key-frame files read for the points-per-sweep figure; 0: none

    def __post_init__(self) -> None:
        check_version_name(self.version)
        if self.max_sweeps < 0:
            raise SianmsError(f"--max-sweeps must be >= 0 (0 skips the figure), got {self.max_sweeps}")


def run(config: InfoConfig, out: str | Path | None = None, *, overwrite: bool = False,
        progress: Progress = SILENT) -> dict:
    """The summary of ``config``'s dataset; also written as JSON to ``out`` when given."""
    if out is not None:
        check_writable_output(out, overwrite=overwrite)
    summary = summarize(NuScenesDB(config.dataroot, config.version), config.max_sweeps, progress)
    if out is not None:
        write_json(out, summary)
    return summary


def summarize(db: NuScenesDB, max_sweeps: int = 200, progress: Progress = SILENT) -> dict:
    """Counts and distributions of one dataroot/version as a JSON-ready dict."""
    annotations = db.table("sample_annotation")
    categories = db.annotation_category_names()
    sample_rows = annotations.rows("sample_token")
    n_samples = len(db.table("sample"))
    per_sample = np.bincount(sample_rows, minlength=n_samples)
    cars_per_sample = np.bincount(sample_rows[categories == CAR], minlength=n_samples)
    lidar_points = annotations.column("num_lidar_pts").astype(np.int64)
    overlap, distance = _overlap_and_distance(db)
    cars = categories == CAR
    cars_in_range = cars & (distance < CAR_EVAL_RANGE) & (lidar_points > 0)
    return {
        "dataroot": str(db.dataroot),
        "version": db.version,
        "scenes": len(db.table("scene")),
        "samples": n_samples,
        "sample_data": len(db.table("sample_data")),
        "instances": len(db.table("instance")),
        "annotations": len(annotations),
        "annotations_per_category": dict(Counter(categories.tolist()).most_common()),
        "objects_per_keyframe": _distribution(per_sample),
        "cars_per_keyframe": _distribution(cars_per_sample),
        "cars_per_keyframe_within_50m": float(np.sum(cars_in_range) / max(n_samples, 1)),
        "lidar_points_per_annotation": float(lidar_points.mean()) if len(lidar_points) else 0.0,
        "share_annotations_without_lidar_points": _share(lidar_points == 0),
        "visibility_shares": _visibility_shares(annotations),
        "vehicle_attribute_shares": _attribute_shares(db, "vehicle."),
        "lidar_points_per_sweep": _lidar_points_per_sweep(db, max_sweeps, progress),
        "max_sweeps": max_sweeps,
        "car_share_in_overlap": _share(overlap[cars]),
        "car_share_in_overlap_within_50m_with_points": _share(overlap[cars_in_range]),
        "car_annotations_in_overlap": int(np.sum(overlap & cars)),
    }


def _distribution(values: np.ndarray) -> dict:
    if len(values) == 0:
        return {"mean": 0.0, "median": 0.0, "p10": 0.0, "p90": 0.0, "max": 0}
    return {
        "mean": float(np.mean(values)),
        "median": float(np.median(values)),
        "p10": float(np.percentile(values, 10)),
        "p90": float(np.percentile(values, 90)),
        "max": int(np.max(values)),
    }


def _share(mask: np.ndarray) -> float | None:
    return float(np.mean(mask)) if len(mask) else None


def _visibility_shares(annotations) -> dict:
    tokens = annotations.column("visibility_token")
    counts = Counter(str(t) for t in tokens)
    total = max(sum(counts.values()), 1)
    return {level: counts.get(token, 0) / total for token, level in VISIBILITY_LEVELS.items()}


def _attribute_shares(db: NuScenesDB, prefix: str) -> dict:
    """Shares of the attributes whose name starts with ``prefix`` among annotations carrying one."""
    first_attribute = db.table("sample_annotation").rows("attribute_tokens")
    if first_attribute.shape[1] == 0:
        return {}
    first_attribute = first_attribute[:, 0]
    names = db.table("attribute").column("name")[first_attribute[first_attribute >= 0]]
    chosen = [str(n) for n in names if str(n).startswith(prefix)]
    counts = Counter(chosen)
    return {name: count / len(chosen) for name, count in sorted(counts.items())} if chosen else {}


def _lidar_points_per_sweep(db: NuScenesDB, max_sweeps: int, progress: Progress) -> dict | None:
    """Points per LIDAR_TOP keyframe file, over up to ``max_sweeps`` evenly spread files.

    None when not asked for (``max_sweeps`` 0) or when the dataroot has no LiDAR files (a
    tables-only dataset).
    """
    sample_data = db.table("sample_data")
    tokens = sample_data.tokens[sample_data.column("is_key_frame") & (db.sample_data_channels() == "LIDAR_TOP")]
    if max_sweeps <= 0 or len(tokens) == 0:
        return None
    chosen = [tokens[i] for i in np.unique(np.linspace(0, len(tokens) - 1, min(max_sweeps, len(tokens))).astype(int))]
    if not db.data_path(chosen[0]).exists():
        return None
    progress.start(len(chosen), "sweep", "reading LiDAR")
    counts = np.zeros(len(chosen), dtype=np.int64)
    for i, token in enumerate(chosen):
        counts[i] = len(db.read_lidar(token))
        progress.advance()
    return {"files": len(chosen), **_distribution(counts)}


def _overlap_and_distance(db: NuScenesDB) -> tuple[np.ndarray, np.ndarray]:
    """For every annotation: is its centre in the camera-overlap region of its keyframe (THE
    rule, :func:`sianms_cli.nuscenes.overlap.box_overlap_pairs`, as prepare and metrics decide
    it), and its xy distance to the ego of its LIDAR_TOP key frame (the devkit's range; inf
    without one)."""
    annotations = db.table("sample_annotation")
    centers = annotations.column("translation")
    box_sample = annotations.rows("sample_token")
    overlap = box_overlap_pairs(db, db.table("sample").tokens, box_sample, centers).bits != 0
    rotation, translation, found = lidar_ego_poses(db, np.arange(len(db.table("sample"))))
    centers_ego = centers_in_ego(centers, box_sample, rotation, translation)
    distance = np.where(found[box_sample], np.hypot(centers_ego[:, 0], centers_ego[:, 1]), np.inf)
    return overlap, distance


def format_summary(summary: dict) -> str:
    """The summary as an aligned text report."""
    lines = [
        f"{summary['dataroot']}  {summary['version']}",
        f"  scenes {summary['scenes']}, samples {summary['samples']}, sample_data {summary['sample_data']}, "
        f"instances {summary['instances']}, annotations {summary['annotations']}",
        "  annotations per category:",
    ]
    n_samples = max(summary["samples"], 1)
    for name, count in summary["annotations_per_category"].items():
        lines.append(f"    {name:<40} {count:>9}  {count / n_samples:6.2f} per keyframe")
    objects = summary["objects_per_keyframe"]
    cars = summary["cars_per_keyframe"]
    lines += [
        f"  objects per keyframe: mean {objects['mean']:.1f}, median {objects['median']:.0f}, "
        f"p10-p90 {objects['p10']:.0f}-{objects['p90']:.0f}, max {objects['max']}",
        f"  cars per keyframe: mean {cars['mean']:.1f} (within 50 m with LiDAR points: "
        f"{summary['cars_per_keyframe_within_50m']:.1f})",
        f"  LiDAR points per annotation: mean {summary['lidar_points_per_annotation']:.1f}, "
        f"without any point {_percent(summary['share_annotations_without_lidar_points'])}",
        "  visibility: " + ", ".join(f"{k} {_percent(v)}" for k, v in summary["visibility_shares"].items()),
        "  vehicle attributes: " + ", ".join(
            f"{k.split('.')[-1]} {_percent(v)}" for k, v in summary["vehicle_attribute_shares"].items()),
    ]
    sweeps = summary["lidar_points_per_sweep"]
    lines.append(
        "  LiDAR points per sweep: " + (
            f"mean {sweeps['mean']:.0f}, p10-p90 {sweeps['p10']:.0f}-{sweeps['p90']:.0f}, "
            f"max {sweeps['max']} over {sweeps['files']} keyframe files" if sweeps
            else "not measured (--max-sweeps 0)" if summary["max_sweeps"] == 0 else "no LiDAR files"))
    lines.append(
        f"  cars in the camera-overlap region: {_percent(summary['car_share_in_overlap'])} of all car annotations, "
        f"{_percent(summary['car_share_in_overlap_within_50m_with_points'])} of those within 50 m with LiDAR points")
    return "\n".join(lines)


def _percent(value: float | None) -> str:
    return "n/a" if value is None else f"{100 * value:.1f} %"
