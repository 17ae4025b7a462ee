"""The devkit's box filters (``add_center_dist`` + ``filter_eval_boxes``), as boolean masks.

Applied identically to ground truth and predictions, in the devkit's order:

1. range: keep a box whose ego distance is strictly below its class range. The ego distance
   is the xy norm of (box centre - translation of the ego pose of the sample's LIDAR_TOP key
   frame); classes that the configuration does not evaluate are dropped here;
2. points: drop a ground-truth box without LiDAR or radar point (``num_pts == 0``).
   Predictions are never dropped by this filter;
3. bicycle racks: drop a bicycle or motorcycle whose centre lies in (or on) a
   ``static_object.bicycle_rack`` box of its sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sianms_cli.metrics.boxes import LABEL, RACK_FILTERED
from sianms_cli.metrics.config import DetectionConfig
from sianms_cli.geometry.boxes import points_in_boxes


@dataclass(frozen=True, eq=False)
class FilterResult:
    """Which boxes survive, and how many each filter removed (in order)."""

    kept: np.ndarray
    out_of_range: int
    without_points: int
    in_bicycle_rack: int

    def counts(self) -> dict[str, int]:
        return {"kept": int(self.kept.sum()), "out_of_range": self.out_of_range,
                "without_points": self.without_points, "in_bicycle_rack": self.in_bicycle_rack}


def ego_distance(boxes: np.ndarray, ego_translation: np.ndarray) -> np.ndarray:
    """(N,) xy distance of each box centre from its sample's ego position, metres.

    Computed as the devkit's ``EvalBox.ego_dist``: ``sqrt(dx**2 + dy**2)``.
    """
    offset = boxes["translation"][:, :2] - ego_translation[boxes["sample"], :2]
    with np.errstate(over="ignore"):  # a box 1e200 m away: inf, out of range, as in the devkit
        return np.sqrt(offset[:, 0] ** 2 + offset[:, 1] ** 2)


def in_bicycle_rack(boxes: np.ndarray, racks: np.ndarray) -> np.ndarray:
    """(N,) bool: the box is a bicycle or motorcycle whose centre lies inside, bounds included,
    one of the rack boxes of its sample (the devkit's ``points_in_box`` test)."""
    inside = np.zeros(len(boxes), dtype=bool)
    if len(racks) == 0:
        return inside
    candidates = np.isin(boxes["label"], [LABEL[name] for name in RACK_FILTERED])
    candidates &= np.isin(boxes["sample"], racks["sample"])
    rows = np.flatnonzero(candidates)
    for sample in np.unique(boxes["sample"][rows]):
        mine = rows[boxes["sample"][rows] == sample]
        sample_racks = racks[racks["sample"] == sample]
        membership = points_in_boxes(boxes["translation"][mine], sample_racks["translation"],
                                     sample_racks["size"], sample_racks["rotation"])
        inside[mine] = membership.any(axis=0)
    return inside


def filter_boxes(boxes: np.ndarray, ego_translation: np.ndarray, racks: np.ndarray,
                 config: DetectionConfig, *, ground_truth: bool) -> FilterResult:
    """The mask of boxes the devkit keeps.

    Args:
        boxes: box table whose ``sample`` indexes ``ego_translation``.
        ego_translation: (S, 3) ego position of each sample (LIDAR_TOP key frame), global.
        racks: bicycle-rack boxes (``sample`` in the same index space).
        config: gives the class ranges (classes it does not name are dropped).
        ground_truth: apply the zero-points filter (ground truth only).
    """
    in_range = ego_distance(boxes, ego_translation) < config.range_by_label()[boxes["label"]]
    with_points = in_range & ~(ground_truth & (boxes["num_pts"] == 0))
    kept = with_points & ~in_bicycle_rack(boxes, racks)  # per-box tests: the order only matters for counts
    return FilterResult(kept, int(len(boxes) - in_range.sum()), int(in_range.sum() - with_points.sum()),
                        int(with_points.sum() - kept.sum()))
