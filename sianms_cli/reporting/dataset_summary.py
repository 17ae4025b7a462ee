"""Figures that describe a nuScenes-format dataset, for `sianms info`.

The same figures are published for real nuScenes (docs/synthetic_world.md#nuscenes-figures), so
any dataroot, synthetic or real, can be held against the real one line by line: the text
report prints each figure beside its nuScenes value and source
(:mod:`sianms_cli.reporting.nuscenes_reference`). The figures that decide how often one object
is seen twice, which siaNMS exists for, are the image boxes per 3-D box (the devkit's 2-D
export rule, :mod:`sianms_cli.reporting.image_boxes`), the share imaged by two or more cameras
by class and distance, the overlap share, the car azimuth and heading histograms and the ego's
turns (:mod:`sianms_cli.reporting.ego_motion`).
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sianms_cli.errors import SianmsError
from sianms_cli.metrics.config import DETECTION_CVPR_2019
from sianms_cli.geometry.quaternion import quat_to_matrix
from sianms_cli.io import check_outside_dataroot, check_writable_output, json_text, real_path, write_files_together
from sianms_cli.progress import SILENT, Progress
from sianms_cli.nuscenes.classes import CATEGORY_TO_DETECTION, DETECTION_CLASSES
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.overlap import box_overlap_pairs, centers_in_ego, lidar_ego_poses
from sianms_cli.nuscenes.tables import check_version_name
from sianms_cli.reporting.ego_motion import COMMAND_LATERAL_M, TURN_DEGREES, ego_motion
from sianms_cli.reporting.image_boxes import annotation_image_boxes
from sianms_cli.reporting.nuscenes_reference import REFERENCE, reference_json, reference_per_name
from sianms_cli.synth.marker import read_marker

CAR = "vehicle.car"
HUMAN_PREFIX = "human."  # the devkit#457 "humans": every human.* category
CAR_EVAL_RANGE = float(DETECTION_CVPR_2019["class_range"]["car"])  # the devkit's class range for cars
DISTANCE_BANDS_M = (0.0, 10.0, 20.0, 30.0, 50.0)
CLASS_RANGE_BANDS_M = (0.0, 20.0, 30.0, 40.0, 50.0)  # the bands of the published val figures
POINT_BANDS_M = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0, np.inf)  # LiDAR points per annotation by distance
AZIMUTH_BIN_DEGREES = 15.0
FORE_AFT_DEGREES = 15.0  # half-width of the fore-aft sectors (ahead and behind)
HEADING_BIN_DEGREES = 5.0
VISIBILITY_LEVELS = {"1": "v0-40", "2": "v40-60", "3": "v60-80", "4": "v80-100"}
FULLY_VISIBLE_TOKEN = "4"  # v80-100
# Scene conditions as nuScenes descriptions write them ("Night, big street, ...", "Rain, peds,
# parking lot", "Night, rain, ..."): a word that starts with "night" or "rain", any case, so
# "rainy" counts and "train" or "drain" do not.
NIGHT_WORD = re.compile(r"\bnight", re.IGNORECASE)
RAIN_WORD = re.compile(r"\brain", re.IGNORECASE)


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


def run(config: InfoConfig, out: str | Path | None = None, *, contact_sheet: str | Path | None = None,
        overwrite: bool = False, progress: Progress = SILENT) -> dict:
    """The summary of ``config``'s dataset; also written as JSON to ``out``, and the dataset's contact
    sheet drawn into ``contact_sheet`` (:mod:`.contact_sheet`; its rows in the summary), when given.

    Both outputs are checked before any work and written once both are made: a bad picture name
    or an image that does not decode leaves neither.
    """
    if contact_sheet is not None and out is not None and real_path(contact_sheet) == real_path(out):
        raise SianmsError(f"--contact-sheet: {contact_sheet} is also --out; give each its own file")
    for path, flag in ((out, "--out"), (contact_sheet, "--contact-sheet")):
        if path is not None:
            check_outside_dataroot(path, config.dataroot, flag, "info")
            check_writable_output(path, overwrite=overwrite)
    if contact_sheet is not None:
        from sianms_cli.reporting.contact_sheet import sheet_format

        sheet_format(contact_sheet)
    db = NuScenesDB(config.dataroot, config.version)
    summary = summarize(db, config.max_sweeps, progress)
    contents: dict[Path, str | bytes] = {}
    if contact_sheet is not None:
        from sianms_cli.reporting.contact_sheet import pick_rows, render_contact_sheet, sheet_bytes

        rows = pick_rows(db)
        contents[Path(contact_sheet)] = sheet_bytes(render_contact_sheet(db, rows), contact_sheet)
        summary["contact_sheet"] = {"path": str(contact_sheet),
                                    "rows": [{"condition": row.condition, "scene": row.scene_name} for row in rows]}
    if out is not None:
        contents[Path(out)] = json_text(summary)
    write_files_together(contents, overwrite=overwrite)  # both or neither, the files they replace put back
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
    radar_points = annotations.column("num_radar_pts").astype(np.int64)
    overlap, centers_ego, ego_rotation = _overlap_and_ego_frame(db)
    distance = np.hypot(centers_ego[:, 0], centers_ego[:, 1])
    cars = categories == CAR
    cars_within_50m = cars & (distance < CAR_EVAL_RANGE)
    cars_in_range = cars_within_50m & (lidar_points > 0)
    classes, humans = _detection_classes(categories)
    image = annotation_image_boxes(db, progress)
    cameras = image.imaged.sum(axis=1)
    heading_ego = _headings_in_ego(annotations.column("rotation")[cars_within_50m],
                                   ego_rotation[sample_rows[cars_within_50m]])
    return {
        "dataroot": str(db.dataroot),
        "version": db.version,
        "synth_marker": read_marker(db.dataroot),  # None for a dataset sianms synth did not write
        "scenes": len(db.table("scene")),
        "scene_conditions": condition_counts(db.table("scene").column("description").tolist()),
        "samples": n_samples,
        "sample_data": len(db.table("sample_data")),
        "instances": len(db.table("instance")),
        "annotations": len(annotations),
        "annotations_per_category": dict(Counter(categories.tolist()).most_common()),
        "objects_per_keyframe": _distribution(per_sample),
        "objects_per_keyframe_by_class": {
            name: float(np.sum(classes == name) / max(n_samples, 1)) for name in DETECTION_CLASSES},
        "cars_per_keyframe": _distribution(cars_per_sample),
        "cars_per_keyframe_within_50m": float(np.sum(cars_in_range) / max(n_samples, 1)),
        "lidar_points_per_annotation": float(lidar_points.mean()) if len(lidar_points) else 0.0,
        "lidar_points_by_distance": lidar_point_band_figures(distance, lidar_points),
        "share_annotations_without_lidar_points": _share(lidar_points == 0),
        "radar_points_per_annotation": float(radar_points.mean()) if len(radar_points) else 0.0,
        "visibility_shares": visibility_shares(annotations.column("visibility_token")),
        "vehicle_attribute_shares": _attribute_shares(db, "vehicle."),
        "lidar_points_per_sweep": _lidar_points_per_sweep(db, max_sweeps, progress),
        "max_sweeps": max_sweeps,
        "car_share_in_overlap": _share(overlap[cars]),
        "car_share_in_overlap_within_50m_with_points": _share(overlap[cars_in_range]),
        "car_annotations_in_overlap": int(np.sum(overlap & cars)),
        "image_boxes": {
            "cameras": list(image.channels),
            **camera_count_figures(cameras),
            "boxes_by_camera_count": np.bincount(cameras, minlength=len(image.channels) + 1).tolist(),
            "humans": camera_count_figures(cameras[humans]),
            "by_class": {name: camera_count_figures(cameras[classes == name])
                         for name in DETECTION_CLASSES if np.any(classes == name)},
            "cars_within_50m_with_points_by_distance": distance_band_figures(
                distance[cars_in_range], cameras[cars_in_range], DISTANCE_BANDS_M),
        },
        "class_range": class_range_figures(classes, distance, n_samples, lidar_points, radar_points,
                                           annotations.column("visibility_token")),
        "car_azimuth_within_50m": azimuth_figures(centers_ego[cars_within_50m, :2]),
        "car_heading_to_axis_within_50m": heading_to_axis_figures(heading_ego),
        "ego_motion": ego_motion(db),
        "nuscenes_reference": reference_json(),
    }


def night_and_rain(descriptions) -> tuple[np.ndarray, np.ndarray]:
    """(N,) bool night and (N,) bool rain of N scene descriptions (see :data:`NIGHT_WORD`)."""
    night = np.array([bool(NIGHT_WORD.search(text)) for text in descriptions], bool)
    rain = np.array([bool(RAIN_WORD.search(text)) for text in descriptions], bool)
    return night, rain


def condition_counts(descriptions: list[str]) -> dict:
    """How many scenes are at night, in rain, and both, read from their descriptions (see
    :data:`NIGHT_WORD`), with their shares of all scenes (None without scenes)."""
    night, rain = night_and_rain(descriptions)
    both = night & rain
    return {
        "night": int(night.sum()), "rain": int(rain.sum()), "night_and_rain": int(both.sum()),
        "share_night": _share(night), "share_rain": _share(rain), "share_night_and_rain": _share(both),
    }


def camera_count_figures(cameras: np.ndarray) -> dict:
    """Image boxes per 3-D box and the shares imaged by >= 2 and by no camera.

    Args:
        cameras: (N,) how many cameras image each 3-D box.
    """
    return {
        "boxes_3d": int(len(cameras)),
        "image_boxes": int(np.sum(cameras)),
        "per_3d_box": float(np.mean(cameras)) if len(cameras) else None,
        "share_imaged_by_2_or_more": _share(cameras >= 2),
        "share_imaged_by_none": _share(cameras == 0),
    }


def distance_band_figures(distance: np.ndarray, cameras: np.ndarray, edges: tuple[float, ...]) -> dict:
    """The share imaged by >= 2 cameras in each ego-distance band [lo, hi) metres.

    Args:
        distance: (N,) xy distance to the ego, metres.
        cameras: (N,) how many cameras image each box.
        edges: increasing band edges, metres.
    """
    band = _band_index(distance, edges)
    figures = {}
    for i, (low, high) in enumerate(zip(edges[:-1], edges[1:])):
        members = band == i
        figures[f"{low:g}-{high:g}"] = {"boxes_3d": int(members.sum()),
                                        "share_imaged_by_2_or_more": _share(cameras[members] >= 2)}
    return figures


def lidar_point_band_figures(distance: np.ndarray, lidar_points: np.ndarray,
                              edges: tuple[float, ...] = POINT_BANDS_M) -> dict:
    """Where the mean LiDAR points per annotation come from: per ego-distance band [lo, hi),
    the share of the annotations, their mean and median points, and the band's part of the
    overall mean (the parts sum to it). A few boxes beside the ego hold hundreds of points
    each, so the overall mean is mostly theirs.

    Args:
        distance: (N,) xy distance to the ego, metres (inf without a LIDAR_TOP key frame).
        lidar_points: (N,) ``num_lidar_pts``.
    """
    band = np.minimum(_band_index(distance, edges), len(edges) - 2)  # inf: the last band
    total = max(len(distance), 1)
    figures = {}
    for i, (low, high) in enumerate(zip(edges[:-1], edges[1:])):
        points = lidar_points[band == i]
        figures[f"{low:g}-{high:g}"] = {
            "share": len(points) / total,
            "mean": float(points.mean()) if len(points) else None,
            "median": float(np.median(points)) if len(points) else None,
            "part_of_mean": float(points.sum() / total),
        }
    return figures


def class_range_figures(classes: np.ndarray, distance: np.ndarray, n_samples: int, lidar_points: np.ndarray,
                        radar_points: np.ndarray, visibility_tokens: np.ndarray,
                        class_range: dict = DETECTION_CVPR_2019["class_range"]) -> dict:
    """How much of what is annotated the detection benchmark evaluates: the share of each
    class's boxes inside its class range (ego distance strictly below it, as the devkit
    filters), those boxes per keyframe, how the in-range boxes spread over distance, how
    many of them hold no LiDAR point, no radar return, or neither (the devkit drops the last;
    also per class, per distance band and per visibility level: how closely the labelled
    visibility follows what the sensors saw), and how visible they are (nuScenes' published
    visibility shares are of in-range boxes).

    Args:
        classes: (N,) detection class of each annotation, "" for one that is not evaluated.
        distance: (N,) xy distance to the ego of its LIDAR_TOP key frame, metres (inf without one).
        n_samples: keyframes of the dataset.
        lidar_points, radar_points: (N,) ``num_lidar_pts`` and ``num_radar_pts``.
        visibility_tokens: (N,) ``visibility_token`` "1".."4".
        class_range: {detection class: range in metres}.
    """
    members = {name: classes == name for name in class_range}
    limit = np.zeros(len(classes))  # 0 m: an unevaluated class is never in range
    for name, member in members.items():
        limit[member] = class_range[name]
    evaluated = classes != ""
    in_range = evaluated & (distance < limit)
    keyframes = max(n_samples, 1)
    edges = CLASS_RANGE_BANDS_M
    band = _band_index(distance[in_range], edges)
    band_names = [f"{low:g}-{high:g}" for low, high in zip(edges[:-1], edges[1:])]
    empty = (lidar_points == 0) & (radar_points == 0)
    return {
        "share_in_class_range": _share(in_range[evaluated]),
        "per_keyframe_in_class_range": float(in_range.sum() / keyframes),
        "by_class": {name: {"share_in_class_range": _share(in_range[member]),
                            "per_keyframe_in_class_range": float(np.sum(in_range[member]) / keyframes),
                            "share_without_lidar_or_radar_points": _share(empty[in_range & member])}
                     for name, member in members.items() if member.any()},
        "distance_band_shares": {name: _share(band == i) for i, name in enumerate(band_names)},
        "share_without_lidar_or_radar_points_by_distance_band": {
            name: _share(empty[in_range][band == i]) for i, name in enumerate(band_names)},
        "share_without_lidar_points": _share(lidar_points[in_range] == 0),
        "share_without_radar_points": _share(radar_points[in_range] == 0),
        "share_without_lidar_or_radar_points": _share(empty[in_range]),
        "visibility_shares": visibility_shares(visibility_tokens[in_range]),
        "share_fully_visible_by_distance_band": {
            name: _share(visibility_tokens[in_range][band == i] == FULLY_VISIBLE_TOKEN)
            for i, name in enumerate(band_names)},
        "share_without_lidar_or_radar_points_by_visibility": {
            level: _share(empty[in_range & (visibility_tokens == token)])
            for token, level in VISIBILITY_LEVELS.items()},
    }


def azimuth_figures(xy_ego: np.ndarray) -> dict:
    """Histogram of the azimuth (ego frame, 0 ahead, CCW) of box centres, and its fore-aft share.

    Real cars concentrate ahead of and behind the ego (same lane); azimuth decides which
    cameras, and which seams, see an object.

    Args:
        xy_ego: (N, 2) centres in the ego frame.

    Returns:
        counts per ``AZIMUTH_BIN_DEGREES`` bin from -180°, the share within ``FORE_AFT_DEGREES``
        of the fore-aft axis (ahead or behind; 60/360 if uniform) and the number of empty bins.
    """
    azimuth = np.degrees(np.arctan2(xy_ego[:, 1], xy_ego[:, 0]))
    counts, _ = np.histogram(azimuth, bins=np.arange(-180.0, 180.0 + AZIMUTH_BIN_DEGREES, AZIMUTH_BIN_DEGREES))
    from_axis = np.minimum(np.abs(azimuth), 180.0 - np.abs(azimuth))
    return {
        "boxes": int(len(azimuth)),
        "bin_degrees": AZIMUTH_BIN_DEGREES,
        "counts_from_minus_180": counts.tolist(),
        "share_within_15deg_of_fore_aft_axis": _share(from_axis <= FORE_AFT_DEGREES),
        "empty_bins": int(np.sum(counts == 0)) if len(azimuth) else None,
    }


def heading_to_axis_figures(heading_ego: np.ndarray) -> dict:
    """Histogram of the angle between each heading and the nearest ego axis (0-45°).

    Parked and same-lane cars sit near 0°; turning, crossing and angled traffic fill the rest.

    Args:
        heading_ego: (N,) headings in the ego frame, radians.
    """
    folded = np.mod(np.degrees(heading_ego), 90.0)
    to_axis = np.minimum(folded, 90.0 - folded)
    counts, _ = np.histogram(to_axis, bins=np.arange(0.0, 45.0 + HEADING_BIN_DEGREES, HEADING_BIN_DEGREES))
    return {
        "boxes": int(len(to_axis)),
        "bin_degrees": HEADING_BIN_DEGREES,
        "counts_from_0": counts.tolist(),
        "share_within_5deg_of_axis": _share(to_axis < HEADING_BIN_DEGREES),
    }


def _headings_in_ego(box_rotation: np.ndarray, ego_rotation: np.ndarray) -> np.ndarray:
    """(N,) yaw of each box's forward axis in its ego frame: ``R_ego^T R_box x``."""
    if len(box_rotation) == 0:
        return np.zeros(0)
    forward = np.einsum("nji,nj->ni", quat_to_matrix(ego_rotation), quat_to_matrix(box_rotation)[:, :, 0])
    return np.arctan2(forward[:, 1], forward[:, 0])


def _detection_classes(categories: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N,) detection class of each annotation ("" when not evaluated) and (N,) is-human."""
    names, inverse = np.unique(categories, return_inverse=True)
    classes = np.array([CATEGORY_TO_DETECTION.get(str(name), "") for name in names], dtype="U32")
    humans = np.array([str(name).startswith(HUMAN_PREFIX) for name in names], dtype=bool)
    return classes[inverse], humans[inverse]


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


def _band_index(distance: np.ndarray, edges: tuple[float, ...]) -> np.ndarray:
    """(N,) index i of the band [edges[i], edges[i + 1]) holding each distance; -1 below the
    first edge, len(edges) - 1 at or beyond the last."""
    return np.searchsorted(np.asarray(edges), distance, side="right") - 1


def _share(mask: np.ndarray) -> float | None:
    return float(np.mean(mask)) if len(mask) else None


def visibility_shares(tokens: np.ndarray) -> dict:
    """Shares of the visibility levels (0-40 ... 80-100 %) among annotations' ``visibility_token``s."""
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

    None when not asked for (``max_sweeps`` 0) or when the dataroot has none of those files (a
    tables-only dataset); some of them missing is an error naming the first.
    """
    sample_data = db.table("sample_data")
    tokens = sample_data.tokens[sample_data.column("is_key_frame") & (db.sample_data_channels() == "LIDAR_TOP")]
    if max_sweeps <= 0 or len(tokens) == 0:
        return None
    chosen = [tokens[i] for i in np.unique(np.linspace(0, len(tokens) - 1, min(max_sweeps, len(tokens))).astype(int))]
    if not any(db.data_path(token).exists() for token in chosen):
        return None
    progress.start(len(chosen), "sweep", "reading LiDAR")
    counts = np.zeros(len(chosen), dtype=np.int64)
    for i, token in enumerate(chosen):
        counts[i] = len(db.read_lidar(token))
        progress.advance()
    return {"files": len(chosen), **_distribution(counts)}


def _overlap_and_ego_frame(db: NuScenesDB) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For every annotation: is its centre in the camera-overlap region of its keyframe (THE
    rule, :func:`sianms_cli.nuscenes.overlap.box_overlap_pairs`, as prepare and metrics decide
    it), and its centre in the ego frame of its LIDAR_TOP key frame (the devkit's range; inf
    without one); and the (S, 4) ego rotation of every sample."""
    annotations = db.table("sample_annotation")
    centers = annotations.column("translation")
    box_sample = annotations.rows("sample_token")
    overlap = box_overlap_pairs(db, db.table("sample").tokens, box_sample, centers).bits != 0
    rotation, translation, found = lidar_ego_poses(db, np.arange(len(db.table("sample"))))
    centers_ego = np.where(found[box_sample, None], centers_in_ego(centers, box_sample, rotation, translation),
                           np.inf)
    return overlap, centers_ego, rotation


def format_summary(summary: dict) -> str:
    """The summary as an aligned text report: each figure as "ours | nuScenes value (source)"."""
    lines = [
        f"{summary['dataroot']}  {summary['version']}",
        *_synth_marker_lines(summary["synth_marker"]),
        f"  scenes {summary['scenes']}, samples {summary['samples']}, sample_data {summary['sample_data']}, "
        f"instances {summary['instances']}, annotations {summary['annotations']}",
        *_condition_lines(summary["scene_conditions"], summary["scenes"]),
        "  annotations per category:",
    ]
    n_samples = max(summary["samples"], 1)
    for name, count in summary["annotations_per_category"].items():
        lines.append(f"    {name:<40} {count:>9}  {count / n_samples:6.2f} per keyframe")
    objects = summary["objects_per_keyframe"]
    cars = summary["cars_per_keyframe"]
    lines += [
        f"  objects per keyframe: mean {objects['mean']:.1f}, median {objects['median']:.0f}, "
        f"p10-p90 {objects['p10']:.0f}-{objects['p90']:.0f}, max {objects['max']}"
        + _versus("objects_per_keyframe"),
        "  objects per keyframe by detection class:" + _versus("objects_per_keyframe_by_class"),
    ]
    by_class = reference_per_name("objects_per_keyframe_by_class")
    for name, value in summary["objects_per_keyframe_by_class"].items():
        lines.append(f"    {name:<22} {value:6.2f} | nuScenes {by_class[name]:5.2f}")
    lines += [
        f"  cars per keyframe: mean {cars['mean']:.1f} (within 50 m with LiDAR points: "
        f"{summary['cars_per_keyframe_within_50m']:.1f})",
        f"  LiDAR points per annotation: mean {summary['lidar_points_per_annotation']:.1f}"
        + _versus("lidar_points_per_annotation"),
        "    by distance (share of annotations, mean / median points, part of the mean): " + "; ".join(
            f"{band} m {_percent(v['share'])} {_number(v['mean'], 0)} / {_number(v['median'], 0)}, "
            f"{_number(v['part_of_mean'], 1)}" for band, v in summary["lidar_points_by_distance"].items()),
        f"  annotations without any LiDAR point: {_percent(summary['share_annotations_without_lidar_points'])}"
        + _versus("share_annotations_without_lidar_points"),
        f"  radar returns per annotation: mean {summary['radar_points_per_annotation']:.2f}"
        + _versus("radar_points_per_annotation"),
        "  visibility of all annotations: "
        + ", ".join(f"{k} {_percent(v)}" for k, v in summary["visibility_shares"].items()),
        "  vehicle attributes: " + ", ".join(
            f"{k.split('.')[-1]} {_percent(v)}" for k, v in summary["vehicle_attribute_shares"].items())
        + _versus("vehicle_attribute_shares"),
    ]
    sweeps = summary["lidar_points_per_sweep"]
    lines.append(
        "  LiDAR points per sweep: " + (
            f"mean {sweeps['mean']:.0f}, p10-p90 {sweeps['p10']:.0f}-{sweeps['p90']:.0f}, "
            f"max {sweeps['max']} over {sweeps['files']} keyframe files" if sweeps
            else "not measured (--max-sweeps 0)" if summary["max_sweeps"] == 0 else "no LiDAR files")
        + _versus("lidar_points_per_sweep"))
    lines += _class_range_lines(summary["class_range"])
    lines += _image_box_lines(summary["image_boxes"])
    lines.append(
        f"  cars in the camera-overlap region: {_percent(summary['car_share_in_overlap'])} of all car annotations, "
        f"{_percent(summary['car_share_in_overlap_within_50m_with_points'])} of those within 50 m with LiDAR points"
        + _versus("car_share_in_overlap"))
    lines += _angle_lines(summary["car_azimuth_within_50m"], summary["car_heading_to_axis_within_50m"])
    lines += _ego_lines(summary["ego_motion"])
    return "\n".join(lines)


def _synth_marker_lines(marker: dict | None) -> list[str]:
    """Who wrote a synthetic dataroot, with which seed, on which platform (same seed, other
    platform: other bytes)."""
    if marker is None:
        return []
    config = marker.get("config")
    if not isinstance(config, dict):
        config = {}
    recorded = marker.get("platform")
    if not isinstance(recorded, dict):
        where = "platform not recorded"
    else:
        kernels = f", {recorded['kernels']} kernels" if "kernels" in recorded else ""  # recorded since 0.1.0's AVX2 pin
        where = (f"on {recorded.get('cpu_vendor')} {recorded.get('vector_width')}{kernels}, "
                 f"numpy {recorded.get('numpy')}, numba {recorded.get('numba')}")
    return [f"  written by sianms synth {marker.get('sianms_version')} (seed {config.get('seed')}), {where}"]


def _condition_lines(conditions: dict, scenes: int) -> list[str]:
    """Night and rain scenes, as their descriptions say."""
    return [
        f"  scenes at night (description): {conditions['night']} of {scenes}, {_percent(conditions['share_night'])}"
        + _versus("scene_share_night"),
        f"  scenes in rain (description): {conditions['rain']} of {scenes}, {_percent(conditions['share_rain'])}"
        + _versus("scene_share_rain"),
        f"  scenes at night in rain: {conditions['night_and_rain']}, {_percent(conditions['share_night_and_rain'])}",
    ]


def _class_range_lines(figures: dict) -> list[str]:
    """What the detection benchmark sees of the annotations: its class ranges."""
    share = reference_per_name("share_in_class_range")
    per_keyframe = reference_per_name("per_keyframe_in_class_range")
    empty = reference_per_name("empty_share_by_class")
    lines = [
        f"  inside the devkit's class ranges: {_percent(figures['share_in_class_range'])} of the evaluated boxes"
        + _versus("share_in_class_range"),
        f"    per keyframe: {figures['per_keyframe_in_class_range']:.1f}" + _versus("per_keyframe_in_class_range"),
        f"    {'class':<22} {'in range':>9} {'per keyframe':>13} {'empty':>7}" + _versus("empty_share_by_class"),
    ]
    for name, values in figures["by_class"].items():
        lines.append(f"    {name:<22} {_percent(values['share_in_class_range']):>9} "
                     f"{values['per_keyframe_in_class_range']:>13.2f} "
                     f"{_percent(values['share_without_lidar_or_radar_points']):>7} | {100 * share[name]:.0f} %, "
                     f"{per_keyframe[name]:.2f}, {100 * empty[name]:.1f} %")
    bands = figures["distance_band_shares"]
    lines.append(f"    in-range boxes by distance {' / '.join(bands)} m: "
                 + " / ".join(_percent(value) for value in bands.values())
                 + _versus("class_range_distance_band_shares"))
    lines.append("    in-range boxes without a LiDAR point / radar return / either: "
                 + " / ".join(_percent(figures[key]) for key in (
                     "share_without_lidar_points", "share_without_radar_points",
                     "share_without_lidar_or_radar_points"))
                 + _versus("class_range_empty_shares"))
    empty_by_band = figures["share_without_lidar_or_radar_points_by_distance_band"]
    lines.append(f"    in-range boxes without LiDAR or radar by distance {' / '.join(empty_by_band)} m: "
                 + " / ".join(_percent(v) for v in empty_by_band.values()) + _versus("empty_share_by_distance_band"))
    lines.append("    in-range visibility: " + ", ".join(
        f"{k} {_percent(v)}" for k, v in figures["visibility_shares"].items()) + _versus("visibility_shares"))
    fully_visible = figures["share_fully_visible_by_distance_band"]
    lines.append(f"    in-range boxes 80-100 % visible by distance {' / '.join(fully_visible)} m: "
                 + " / ".join(_percent(v) for v in fully_visible.values()) + " | nuScenes: not published")
    lines.append("    in-range boxes without LiDAR or radar by visibility: " + ", ".join(
        f"{k} {_percent(v)}" for k, v in figures["share_without_lidar_or_radar_points_by_visibility"].items())
        + _versus("empty_share_by_visibility"))
    return lines


def _image_box_lines(image: dict) -> list[str]:
    """The duplicate figures: image boxes per 3-D box and the share imaged twice, by class and range."""
    humans = image["humans"]
    lines = [
        f"  image boxes (devkit 2-D export rule over {len(image['cameras'])} cameras):",
        f"    per 3-D box: {_number(image['per_3d_box'], 3)}" + _versus("image_boxes_per_3d_box"),
        f"    per human 3-D box: {_number(humans['per_3d_box'], 3)}" + _versus("human_image_boxes_per_3d_box"),
        f"    3-D boxes imaged by >= 2 cameras: {_percent(image['share_imaged_by_2_or_more'])}"
        + _versus("share_imaged_by_2_or_more"),
        f"    human 3-D boxes imaged by >= 2 cameras: {_percent(humans['share_imaged_by_2_or_more'])}"
        + _versus("human_share_imaged_by_2_or_more"),
        f"    3-D boxes imaged by no camera: {_percent(image['share_imaged_by_none'])}",
        f"    {'class':<22} {'3-D boxes':>9} {'per box':>8} {'>= 2 cameras':>13}",
    ]
    for name, figures in image["by_class"].items():
        lines.append(f"    {name:<22} {figures['boxes_3d']:>9} {_number(figures['per_3d_box'], 3):>8} "
                     f"{_percent(figures['share_imaged_by_2_or_more']):>13}")
    lines.append("    cars within 50 m with LiDAR points imaged by >= 2 cameras: " + ", ".join(
        f"{band} m {_percent(figures['share_imaged_by_2_or_more'])} ({figures['boxes_3d']})"
        for band, figures in image["cars_within_50m_with_points_by_distance"].items()))
    return lines


def _angle_lines(azimuth: dict, heading: dict) -> list[str]:
    """Where cars stand around the ego and how they are turned against its axes."""
    return [
        f"  car azimuth within 50 m ({azimuth['bin_degrees']:g} deg bins, {azimuth['boxes']} cars): "
        f"within {FORE_AFT_DEGREES:g} deg of the fore-aft axis "
        f"{_percent(azimuth['share_within_15deg_of_fore_aft_axis'])}, "
        f"empty bins {azimuth['empty_bins']} of {len(azimuth['counts_from_minus_180'])}"
        + _versus("car_share_within_15deg_of_fore_aft_axis"),
        "    from -180 deg: " + _shares(azimuth["counts_from_minus_180"]),
        f"  car heading to the nearest ego axis within 50 m ({heading['bin_degrees']:g} deg bins): "
        f"within {heading['bin_degrees']:g} deg {_percent(heading['share_within_5deg_of_axis'])}"
        + _versus("car_share_heading_within_5deg_of_axis"),
        "    from 0 deg: " + _shares(heading["counts_from_0"]),
    ]


def _ego_lines(motion: dict) -> list[str]:
    """How much of the driving is simply going straight."""
    return [
        f"  ego going straight (|lateral| < {COMMAND_LATERAL_M:g} m at 3 s): "
        f"{_percent(motion['share_keyframes_go_straight'])} of {motion['keyframes_with_command']} keyframes"
        + _versus("share_keyframes_go_straight"),
        f"  scenes not simply going straight: {_percent(motion['share_scenes_not_straight'])} of "
        f"{motion['scenes']} (heading span > {TURN_DEGREES:g} deg: {_percent(motion['share_scenes_turning'])})"
        " | nuScenes: not published (the 73.9 % counts planning samples, not scenes)",
    ]


def _versus(key: str) -> str:
    """" | nuScenes VALUE (SOURCE)" for a figure of :data:`REFERENCE`."""
    reference = REFERENCE[key]
    return f" | nuScenes {reference.text} ({reference.source})"


def _shares(counts: list[int]) -> str:
    """Histogram counts as whole percentages of their total."""
    total = max(sum(counts), 1)
    return " ".join(f"{100 * count / total:.0f}" for count in counts) + " %"


def _number(value: float | None, digits: int) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def _percent(value: float | None) -> str:
    return "n/a" if value is None else f"{100 * value:.1f} %"
