"""Bird's-eye pictures of evaluated samples, one panel per method side by side (the paper's Fig. 5).

Each panel, in the ego frame of the sample's LiDAR key frame (x forward, up on the page;
50 m around the car): the LiDAR points in grey, the ground-truth boxes of the evaluated
classes in green, the method's boxes in its colour (a thicker outline for a box made from
a matched pair), and, for the matchers, each kept match's two frustum wedges (dashed, cut
at the maximum detection distance) whose union fed Frustum PointNets.

The samples shown by default are those with the most ground-truth duplicates to find (the
oracle's matches), where duplicate handling matters; choosing them uses the ground truth,
as the scoring does, never the methods' output.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from sianms_cli.detection2d.classes import detection_classes_of
from sianms_cli.metrics.algo import MetricData
from sianms_cli.geometry.bev import bev_corners
from sianms_cli.geometry.quaternion import quat_yaw
from sianms_cli.geometry.transforms import apply_transform, invert_transform, make_transform
from sianms_cli.io import atomic_file
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.evaluation.methods import AllBoxes, split_name

EXTENT_M = 50.0
MAX_POINTS = 40_000  # drawn per panel (a stride through the sweep), so a picture stays light
COLOURS = {"vanilla": "tab:red", "axis-nms": "tab:orange", "rotated-nms": "tab:brown", "circle-nms": "tab:pink",
           "sianms": "tab:blue", "hybrid": "tab:purple", "gated-sianms": "tab:olive", "oracle": "tab:cyan"}


def pick_samples(boxes: AllBoxes, count: int) -> list[int]:
    """The ``count`` samples with the most oracle matches (ground-truth duplicates), earliest first on ties."""
    oracle = boxes.sample[boxes.kind == "oracle"]
    if len(oracle) == 0 or count <= 0:
        return []
    samples, matches = np.unique(oracle, return_counts=True)
    order = np.lexsort((samples, -matches))
    return samples[order[:count]].tolist()


def _ego_frame(db: NuScenesDB, sample_token: str) -> tuple[np.ndarray, np.ndarray]:
    """(global -> ego transform, (P, 2) LiDAR xy in the ego frame) of the sample's LiDAR key frame."""
    lidar = db.keyframe_data(sample_token)["LIDAR_TOP"]
    ego_rotation, ego_translation = db.ego_pose_of(lidar)
    sensor_rotation, sensor_translation, _ = db.calibration_of(lidar)
    points = db.read_lidar(lidar)[:, :3]
    points = points[:: max(1, len(points) // MAX_POINTS)]
    ego = apply_transform(make_transform(sensor_rotation, sensor_translation), points)
    return invert_transform(make_transform(ego_rotation, ego_translation)), ego[:, :2]


def _to_ego(to_ego: np.ndarray, translation: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centres (N, 2) and yaws (N,) of global boxes in the ego frame."""
    centres = apply_transform(to_ego, np.asarray(translation, dtype=np.float64).reshape(-1, 3))[:, :2]
    return centres, np.asarray(yaw) + np.arctan2(to_ego[1, 0], to_ego[0, 0])


def _outline(axes, centres: np.ndarray, sizes: np.ndarray, yaw: np.ndarray, **style) -> None:
    if len(centres) == 0:
        return
    corners = bev_corners(centres, sizes, yaw)
    closed = np.concatenate([corners, corners[:, :1]], axis=1)
    for polygon in closed:  # matplotlib draws one line per call; there are tens per panel
        axes.plot(polygon[:, 1], polygon[:, 0], **style)


def draw_sample(path: Path, db: NuScenesDB, sample_token: str, sample: int, boxes: AllBoxes,
                selections: Mapping[str, np.ndarray], classes: tuple[str, ...]) -> Path:
    """One PNG: a panel per method (``selections``: rows of ``boxes`` each reports)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    to_ego, points = _ego_frame(db, sample_token)
    annotations = db.table("sample_annotation")
    rows = db.sample_annotation_rows(sample_token)
    keep = rows[np.isin(detection_classes_of(db.annotation_category_names()[rows]), classes)]
    gt_centres, gt_yaw = _to_ego(to_ego, annotations.column("translation")[keep],
                                 quat_yaw(annotations.column("rotation")[keep]))
    gt_sizes = annotations.column("size")[keep][:, :2]
    figure, panels = plt.subplots(1, len(selections), figsize=(4.2 * len(selections), 4.6), squeeze=False)
    for axes, (method, selected) in zip(panels[0], selections.items()):
        colour = COLOURS.get(split_name(method)[0], "tab:blue")
        axes.scatter(points[:, 1], points[:, 0], s=0.2, c="0.6", linewidths=0)
        _outline(axes, gt_centres, gt_sizes, gt_yaw, color="tab:green", linewidth=1.0)
        mine = selected[boxes.sample[selected] == sample]
        centres, yaw = _to_ego(to_ego, boxes.translation[mine], boxes.yaw[mine])
        merged = boxes.kind[mine] != "single"
        _outline(axes, centres[~merged], boxes.size[mine][~merged, :2], yaw[~merged], color=colour, linewidth=0.9)
        _outline(axes, centres[merged], boxes.size[mine][merged, :2], yaw[merged], color=colour, linewidth=2.2)
        for wedge in boxes.wedges[mine][merged].reshape(-1, 3, 2):
            corners = apply_transform(to_ego, np.column_stack([wedge, np.zeros(len(wedge))]))[:, :2]
            closed = np.concatenate([corners, corners[:1]])
            axes.plot(closed[:, 1], closed[:, 0], color=colour, linewidth=0.6, linestyle="--")
        axes.set_title(f"{method}: {len(mine)} boxes", fontsize=9)
        axes.set_xlim(EXTENT_M, -EXTENT_M)  # ego y points left: left on the page
        axes.set_ylim(-EXTENT_M, EXTENT_M)
        axes.set_aspect("equal")
        axes.tick_params(labelsize=7)
    figure.suptitle(f"sample {sample_token}  (green: ground truth; thick: a matched pair's box)", fontsize=9)
    return _save(figure, path)


def _reached(curve: MetricData, name: str) -> np.ndarray:
    """A 101-point curve up to the highest recall reached (beyond it, precision is 0 by definition)."""
    return getattr(curve, name)[: curve.max_recall_ind + 1]


def _save(figure, path: Path) -> Path:
    import matplotlib.pyplot as plt

    figure.tight_layout()
    with atomic_file(path) as handle:
        figure.savefig(handle, format="png", dpi=110)
    plt.close(figure)
    return path


def _method_style(method: str) -> dict:
    """One colour per method family; a swept threshold (``axis-nms@0.1``) dotted."""
    return {"color": COLOURS.get(split_name(method)[0]), "linestyle": "-" if "@" not in method else ":",
            "linewidth": 1.2}


def draw_pr_curves(path: Path, curves: Mapping[str, Mapping[str, MetricData]], class_name: str,
                   regions: tuple[str, ...]) -> Path:
    """``pr_curves.png``: precision against recall of ``class_name`` at the TP threshold (2 m), one
    panel per region, one line per method; ``curves``: {method: {region: that class's MetricData}}."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, panels = plt.subplots(1, len(regions), figsize=(5.0 * len(regions), 4.2), squeeze=False)
    for axes, region in zip(panels[0], regions):
        for method, by_region in curves.items():
            curve = by_region[region]
            axes.plot(_reached(curve, "recall"), _reached(curve, "precision"), label=method, **_method_style(method))
        axes.set_title(f"{class_name}, region {region} (2 m)", fontsize=9)
        axes.set_xlabel("recall")
        axes.set_ylabel("precision")
        axes.set_xlim(0, 1)
        axes.set_ylim(0, 1.02)
        axes.grid(alpha=0.3)
    panels[0][-1].legend(fontsize=7, loc="upper right")
    return _save(figure, path)


TP_CURVES = (("trans_err", "ATE (m)"), ("scale_err", "ASE (1 - IoU)"), ("orient_err", "AOE (rad)"))


def draw_tp_curves(path: Path, curves: Mapping[str, Mapping[str, MetricData]], class_name: str,
                   regions: tuple[str, ...], min_recall: float) -> Path:
    """``tp_curves.png``: each TP error of ``class_name`` against recall, as the devkit's
    ``class_tp_curve`` draws it (the cumulative mean over true positives, up to the highest
    recall reached); a row per error, a panel per region, a line per method. The dashed line
    marks ``min_recall``: the reported error is the curve's mean to the right of it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, panels = plt.subplots(len(TP_CURVES), len(regions), figsize=(5.0 * len(regions), 3.2 * len(TP_CURVES)),
                                  squeeze=False)
    for row, (name, label) in zip(panels, TP_CURVES):
        for axes, region in zip(row, regions):
            for method, by_region in curves.items():
                curve = by_region[region]
                axes.plot(_reached(curve, "recall"), _reached(curve, name), label=method, **_method_style(method))
            axes.axvline(min_recall, color="0.5", linestyle="--", linewidth=0.8)
            axes.set_title(f"{class_name}, region {region}: {label}", fontsize=9)
            axes.set_xlabel("recall")
            axes.set_ylabel(label)
            axes.set_xlim(0, 1)
            axes.set_ylim(bottom=0)
            axes.grid(alpha=0.3)
    panels[0][-1].legend(fontsize=7, loc="upper right")
    return _save(figure, path)
