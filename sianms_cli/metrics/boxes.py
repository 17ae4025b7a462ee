"""Detection boxes as one structured numpy array (a *box table*), and the devkit's names.

A box table holds one row per box in :data:`BOX_DTYPE`; predictions and ground truth use
the same layout. Rows keep the devkit's order (samples in their evaluation order, boxes in
list order within a sample), which decides the greedy matching on score ties.

Fields (all in the global frame, nuScenes units):

- ``sample`` int32: index into the evaluation's list of sample tokens;
- ``label`` int8: index into :data:`DETECTION_NAMES`;
- ``attribute`` int8: index into :data:`ATTRIBUTE_NAMES`, :data:`NO_ATTRIBUTE` (-1) for ``""``,
  :data:`OTHER_ATTRIBUTE` (-2) for a ground-truth attribute outside the 8 (never equal to a
  prediction's);
- ``translation`` (3,) float64 box centre, metres; ``size`` (3,) float64 (w, l, h), metres;
- ``rotation`` (4,) float64 quaternion (w, x, y, z); ``velocity`` (2,) float64 (vx, vy), m/s,
  NaN where unknown;
- ``score`` float64: detection score; -1 for ground truth;
- ``num_pts`` int32: LiDAR + radar points of a ground-truth box; -1 for predictions.
"""

from __future__ import annotations

import numpy as np

from sianms_cli.nuscenes.classes import DETECTION_CLASSES

DETECTION_NAMES: tuple[str, ...] = DETECTION_CLASSES
"""The 10 detection classes of the nuScenes detection task, in the devkit's order."""

ATTRIBUTE_NAMES: tuple[str, ...] = (
    "pedestrian.moving", "pedestrian.sitting_lying_down", "pedestrian.standing",
    "cycle.with_rider", "cycle.without_rider",
    "vehicle.moving", "vehicle.parked", "vehicle.stopped",
)
"""The 8 attribute names a result may carry (or ``""``), in the devkit's order."""

NO_ATTRIBUTE = -1
OTHER_ATTRIBUTE = -2

TP_METRICS: tuple[str, ...] = ("trans_err", "scale_err", "orient_err", "vel_err", "attr_err")
"""The five true-positive error metrics, in the devkit's order (ATE, ASE, AOE, AVE, AAE)."""

BICYCLE_RACK = "static_object.bicycle_rack"
RACK_FILTERED = ("bicycle", "motorcycle")
"""Classes dropped when their centre lies in a bicycle rack of the same sample."""

BOX_DTYPE = np.dtype([
    ("sample", np.int32),
    ("label", np.int8),
    ("attribute", np.int8),
    ("translation", np.float64, (3,)),
    ("size", np.float64, (3,)),
    ("rotation", np.float64, (4,)),
    ("velocity", np.float64, (2,)),
    ("score", np.float64),
    ("num_pts", np.int32),
])

LABEL = {name: index for index, name in enumerate(DETECTION_NAMES)}
ATTRIBUTE = {name: index for index, name in enumerate(ATTRIBUTE_NAMES)}


def empty_boxes(count: int = 0) -> np.ndarray:
    """A zero-filled box table of ``count`` rows (score -1, num_pts -1, attribute "")."""
    boxes = np.zeros(count, dtype=BOX_DTYPE)
    boxes["score"] = -1.0
    boxes["num_pts"] = -1
    boxes["attribute"] = NO_ATTRIBUTE
    return boxes


def make_boxes(
    sample,
    label,
    translation,
    size=(1.0, 1.0, 1.0),
    rotation=(1.0, 0.0, 0.0, 0.0),
    velocity=(0.0, 0.0),
    score=-1.0,
    attribute=NO_ATTRIBUTE,
    num_pts=-1,
) -> np.ndarray:
    """A box table from per-field values, each broadcast to the number of boxes.

    ``label`` and ``attribute`` take indices or names (``""`` for no attribute). For tests,
    benchmarks and pipelines that hold boxes as arrays already; files go through
    :mod:`sianms_cli.metrics.results`.
    """
    translation = np.asarray(translation, dtype=np.float64).reshape(-1, 3)
    count = len(translation)
    boxes = empty_boxes(count)
    boxes["translation"] = translation
    boxes["sample"] = np.broadcast_to(np.asarray(sample), (count,))
    boxes["label"] = _indices(label, LABEL, count)
    boxes["attribute"] = _indices(attribute, {"": NO_ATTRIBUTE, **ATTRIBUTE}, count)
    boxes["size"] = np.broadcast_to(np.asarray(size, dtype=np.float64), (count, 3))
    boxes["rotation"] = np.broadcast_to(np.asarray(rotation, dtype=np.float64), (count, 4))
    boxes["velocity"] = np.broadcast_to(np.asarray(velocity, dtype=np.float64), (count, 2))
    boxes["score"] = np.broadcast_to(np.asarray(score, dtype=np.float64), (count,))
    boxes["num_pts"] = np.broadcast_to(np.asarray(num_pts), (count,))
    return boxes


def _indices(values, table: dict[str, int], count: int) -> np.ndarray:
    values = np.asarray(values)
    if values.dtype.kind in "US":
        values = np.array([table[str(value)] for value in values.reshape(-1)]).reshape(values.shape)
    return np.broadcast_to(values, (count,))
