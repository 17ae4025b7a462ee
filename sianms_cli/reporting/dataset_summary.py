"""Figures that describe a nuScenes-format dataset, for `sianms info`.

The same figures are published for real nuScenes (``shared/reference/nuscenes.md`` §9),
so a synthetic dataroot can be compared with the real one line by line.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from sianms_cli.geometry.transforms import apply_transform, invert_transform, make_transform
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.rigs import sample_rigs

CAR = "vehicle.car"
CAR_EVAL_RANGE = 50.0  # the devkit's class range for cars (detection_cvpr_2019)
VISIBILITY_LEVELS = {"1": "v0-40", "2": "v40-60", "3": "v60-80", "4": "v80-100"}


def summarize(db: NuScenesDB, max_sweeps: int = 200) -> dict:
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
        "lidar_points_per_sweep": _lidar_points_per_sweep(db, max_sweeps),
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


def _lidar_points_per_sweep(db: NuScenesDB, max_sweeps: int) -> dict | None:
    """Points per LIDAR_TOP keyframe file, over up to ``max_sweeps`` evenly spread files.

    None when the dataroot has no LiDAR files (a tables-only dataset).
    """
    sample_data = db.table("sample_data")
    tokens = sample_data.tokens[sample_data.column("is_key_frame") & (db.sample_data_channels() == "LIDAR_TOP")]
    if max_sweeps <= 0 or len(tokens) == 0:
        return None
    chosen = [tokens[i] for i in np.unique(np.linspace(0, len(tokens) - 1, min(max_sweeps, len(tokens))).astype(int))]
    if not db.data_path(chosen[0]).exists():
        return None
    counts = np.array([len(db.read_lidar(token)) for token in chosen])
    return {"files": len(chosen), **_distribution(counts)}


def _overlap_and_distance(db: NuScenesDB) -> tuple[np.ndarray, np.ndarray]:
    """For every annotation: is its centre in the camera-overlap region of its keyframe
    (``CameraRig.in_overlap``), and its xy distance to the ego (the devkit's range)."""
    annotations = db.table("sample_annotation")
    centers = annotations.column("translation")
    overlap = np.zeros(len(annotations), dtype=bool)
    distance = np.full(len(annotations), np.inf)
    sample_tokens = db.table("sample").tokens
    rigs, rig_of_sample = sample_rigs(db, sample_tokens)
    for sample_token, rig in zip(sample_tokens, rig_of_sample.tolist()):
        rows = db.sample_annotation_rows(sample_token)
        data = db.keyframe_data(sample_token)
        if len(rows) == 0 or "LIDAR_TOP" not in data:
            continue
        rotation, translation = db.ego_pose_of(data["LIDAR_TOP"])
        centers_ego = apply_transform(invert_transform(make_transform(rotation, translation)), centers[rows])
        distance[rows] = np.hypot(centers_ego[:, 0], centers_ego[:, 1])
        if rig >= 0:
            overlap[rows] = rigs[rig].in_overlap(centers_ego)
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
            f"max {sweeps['max']} over {sweeps['files']} keyframe files" if sweeps else "no LiDAR files"))
    lines.append(
        f"  cars in the camera-overlap region: {_percent(summary['car_share_in_overlap'])} of all car annotations, "
        f"{_percent(summary['car_share_in_overlap_within_50m_with_points'])} of those within 50 m with LiDAR points")
    return "\n".join(lines)


def _percent(value: float | None) -> str:
    return "n/a" if value is None else f"{100 * value:.1f} %"
