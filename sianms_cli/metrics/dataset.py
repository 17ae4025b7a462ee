"""What the detection evaluation reads from a nuScenes-format dataset, as arrays.

- :func:`eval_split`: the samples of a split in the devkit's order (sample-table order of the
  samples whose scene name is in the split; this is also the order in which the devkit
  flattens predictions of a custom split);
- :func:`ground_truth`: the split's annotations of the 10 detection classes as a box table,
  with the devkit's GT velocity (``NuScenes.box_velocity``), ``num_pts`` (LiDAR + radar) and
  attribute;
- :func:`ego_poses`: per sample, the ego pose of its LIDAR_TOP key frame (the devkit's
  reference for the range filter);
- :func:`bicycle_racks`: the ``static_object.bicycle_rack`` boxes of each sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.metrics.boxes import (
    ATTRIBUTE,
    BICYCLE_RACK,
    LABEL,
    NO_ATTRIBUTE,
    OTHER_ATTRIBUTE,
    empty_boxes,
)
from sianms_cli.nuscenes.classes import CATEGORY_TO_DETECTION
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.overlap import LIDAR_CHANNEL, lidar_ego_poses
from sianms_cli.nuscenes.splits import PREDEFINED_SPLITS, split_scene_names

MAX_TIME_DIFF = 1.5  # seconds between annotations for the devkit's velocity estimate (x2 centred)


@dataclass(frozen=True, eq=False)
class EvalSplit:
    """The samples a split evaluates, in the devkit's order.

    Attributes:
        name: the split name.
        predefined: a devkit split (train, val, mini_val, ...) rather than one from
            ``<version>/splits.json``; decides how results are matched to samples.
        sample_tokens: (S,) the samples, in sample-table order.
        sample_rows: (S,) int64 their rows in the sample table.
    """

    name: str
    predefined: bool
    sample_tokens: tuple[str, ...]
    sample_rows: np.ndarray

    def __len__(self) -> int:
        return len(self.sample_tokens)


def eval_split(db: NuScenesDB, split: str) -> EvalSplit:
    """The split's samples in sample-table order (the devkit's ``get_samples_of_scenes``).

    Raises SianmsError for a predefined split that does not fit the version or a split with
    no sample in this dataset, DataFormatError for a missing or malformed splits.json or a
    split scene whose sample chain is broken (:meth:`NuScenesDB.sample_tokens_of_scene`).
    """
    names = set(split_scene_names(split, db.version, db.dataroot))
    scenes = db.table("scene")
    in_split = np.array([name in names for name in scenes.column("name").tolist()], dtype=bool)
    for scene in scenes.tokens[in_split].tolist():  # a sample.json fault is blamed on sample.json, not the results
        db.sample_tokens_of_scene(scene)
    samples = db.table("sample")
    rows = np.flatnonzero(in_split[samples.rows("scene_token")]) if len(samples) else np.zeros(0, np.int64)
    if len(rows) == 0 and split not in PREDEFINED_SPLITS:
        raise DataFormatError(db.table_root / "splits.json", f"none of the split's {len(names)} scenes has a sample "
                              f"in {db.table_root / 'scene.json'}", field=split)
    if len(rows) == 0:
        raise SianmsError(
            f"split '{split}' holds no sample of {db.table_root} (its {len(names)} scenes are not in scene.json)"
        )
    return EvalSplit(split, split in PREDEFINED_SPLITS, tuple(samples.tokens[rows].tolist()), rows)


def ego_poses(db: NuScenesDB, split: EvalSplit) -> tuple[np.ndarray, np.ndarray]:
    """(rotation (S, 4) w,x,y,z, translation (S, 3) m) of each sample's LIDAR_TOP key frame.

    The pose the overlap rule uses too (:func:`sianms_cli.nuscenes.overlap.lidar_ego_poses`;
    a later key frame of the channel wins, as the devkit's ``sample['data']``). A sample
    without one raises DataFormatError: the devkit needs it for the range filter.
    """
    rotation, translation, found = lidar_ego_poses(db, split.sample_rows)
    if not found.all():
        token = split.sample_tokens[int(np.flatnonzero(~found)[0])]
        raise DataFormatError(db.table("sample").path, f"has no {LIDAR_CHANNEL} key frame, whose ego pose the "
                              "evaluation needs", token=token, field="data")
    return rotation, translation


def _split_index(db: NuScenesDB, split: EvalSplit) -> np.ndarray:
    """(rows of sample table,) int64: index of each sample in the split, -1 outside it."""
    index = np.full(len(db.table("sample")), -1, dtype=np.int64)
    index[split.sample_rows] = np.arange(len(split))
    return index


def _categories(db: NuScenesDB) -> tuple[np.ndarray, np.ndarray]:
    """(category names (C,), category row of every annotation (N,)): rows, not N strings."""
    categories = db.table("instance").rows("category_token")[db.table("sample_annotation").rows("instance_token")]
    return db.table("category").column("name"), categories


def _annotations_in_split(db: NuScenesDB, split: EvalSplit, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(annotation rows, their split sample index) for annotations with ``keep``, ordered by
    sample (split order) then file order (the devkit's ``sample['anns']``)."""
    annotations = db.table("sample_annotation")
    sample_of = _split_index(db, split)[annotations.rows("sample_token")]
    rows = np.flatnonzero(keep & (sample_of >= 0))
    rows = rows[np.argsort(sample_of[rows], kind="stable")]
    return rows, sample_of[rows]


def ground_truth(db: NuScenesDB, split: EvalSplit) -> tuple[np.ndarray, np.ndarray]:
    """The split's ground truth of the detection classes, before any filter.

    Returns:
        ``(boxes, annotation_rows)``: the box table (``sample`` = index in ``split``, score
        -1) and (N,) int64 each box's row in sample_annotation (for messages).

    Raises DataFormatError naming the annotation for one with more than one attribute, as
    the devkit refuses it.
    """
    annotations = db.table("sample_annotation")
    names, category_of_row = _categories(db)
    label_of_category = np.array([LABEL.get(CATEGORY_TO_DETECTION.get(str(n), ""), -1) for n in names],
                                 dtype=np.int64)
    label_of_row = label_of_category[category_of_row]
    rows, samples = _annotations_in_split(db, split, label_of_row >= 0)

    boxes = empty_boxes(len(rows))
    boxes["sample"] = samples
    boxes["label"] = label_of_row[rows]
    translation = annotations.column("translation")
    boxes["translation"] = translation[rows]
    boxes["size"] = annotations.column("size")[rows]
    boxes["rotation"] = annotations.column("rotation")[rows]
    boxes["num_pts"] = annotations.column("num_lidar_pts")[rows] + annotations.column("num_radar_pts")[rows]
    boxes["attribute"] = _attributes(db, rows)
    boxes["velocity"] = _velocities(db, rows)
    return boxes, rows


def _attributes(db: NuScenesDB, rows: np.ndarray) -> np.ndarray:
    annotations = db.table("sample_annotation")
    attribute_rows = annotations.rows("attribute_tokens")[rows]
    counts = (attribute_rows >= 0).sum(axis=1) if attribute_rows.shape[1] else np.zeros(len(rows), np.int64)
    if (counts > 1).any():
        bad = rows[int(np.flatnonzero(counts > 1)[0])]
        raise DataFormatError(annotations.path, "has more than one attribute; the detection evaluation "
                              "allows at most one", token=str(annotations.tokens[bad]), field="attribute_tokens")
    attributes = np.full(len(rows), NO_ATTRIBUTE, dtype=np.int8)
    if attribute_rows.shape[1]:
        names = db.table("attribute").column("name")
        code_of = np.array([ATTRIBUTE.get(str(n), OTHER_ATTRIBUTE) for n in names], dtype=np.int8)
        has = counts == 1
        attributes[has] = code_of[attribute_rows[has, 0]]
    return attributes


def _velocities(db: NuScenesDB, rows: np.ndarray) -> np.ndarray:
    """(N, 2) the devkit's ``box_velocity(token)[:2]``: centred difference over prev/next
    annotations of the instance (one-sided at the ends), NaN for a lone annotation or a gap
    over 1.5 s (3 s centred). Times are sample timestamps in seconds (1e-6 * microseconds)."""
    annotations = db.table("sample_annotation")
    previous = annotations.rows("prev")[rows]
    following = annotations.rows("next")[rows]
    has_prev, has_next = previous >= 0, following >= 0
    first = np.where(has_prev, previous, rows)
    last = np.where(has_next, following, rows)
    translation = annotations.column("translation")
    timestamps = db.table("sample").column("timestamp")[annotations.rows("sample_token")]
    time_diff = 1e-6 * timestamps[last] - 1e-6 * timestamps[first]
    max_diff = np.where(has_prev & has_next, 2 * MAX_TIME_DIFF, MAX_TIME_DIFF)
    with np.errstate(divide="ignore", invalid="ignore"):
        velocity = (translation[last, :2] - translation[first, :2]) / time_diff[:, None]
    unknown = ~(has_prev | has_next) | (time_diff > max_diff)
    velocity[unknown] = np.nan
    return velocity


def bicycle_racks(db: NuScenesDB, split: EvalSplit) -> np.ndarray:
    """The ``static_object.bicycle_rack`` annotations of the split as a box table (label 0,
    unused): sample, translation, size, rotation."""
    annotations = db.table("sample_annotation")
    names, category_of_row = _categories(db)
    rows, samples = _annotations_in_split(db, split, np.isin(category_of_row, np.flatnonzero(names == BICYCLE_RACK)))
    racks = empty_boxes(len(rows))
    racks["sample"] = samples
    racks["translation"] = annotations.column("translation")[rows]
    racks["size"] = annotations.column("size")[rows]
    racks["rotation"] = annotations.column("rotation")[rows]
    return racks
