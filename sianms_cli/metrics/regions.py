"""Evaluation regions: all boxes, the camera-overlap region, its complement, one camera pair.

A region is a per-box predicate applied to ground truth and predictions alike before matching.
Overlap is decided by :mod:`sianms_cli.nuscenes.overlap`, the one function `prepare` and `info`
use too: the box centre, in front of the camera, projects inside the images of both cameras
of a contiguous pair of its sample's rig, the centre taken into the ego frame with the ego
pose of the sample's LIDAR_TOP key frame. This module adapts it to the evaluation's box tables.

Region names:

- ``all``: every box;
- ``overlap``: boxes seen by both cameras of at least one contiguous pair;
- ``non-overlap``: every other box;
- ``overlap:CAM_A|CAM_B``: boxes seen by both cameras of that pair (either order);
- ``overlap:*``: shorthand for one region per contiguous pair of the dataset's rigs.
"""

from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np

from sianms_cli.errors import SianmsError
from sianms_cli.geometry.camera_ring import CameraRig
from sianms_cli.nuscenes import overlap as dataset_overlap
from sianms_cli.nuscenes.overlap import OverlapBits

ALL = "all"
OVERLAP = "overlap"
NON_OVERLAP = "non-overlap"
PAIR_PREFIX = "overlap:"
EVERY_PAIR = "overlap:*"


def centers_in_ego(boxes: np.ndarray, ego_rotation: np.ndarray, ego_translation: np.ndarray) -> np.ndarray:
    """(N, 3) centres of a box table in the ego frame of their sample (``boxes["sample"]``
    indexes the (S, 4), (S, 3) poses): :func:`sianms_cli.nuscenes.overlap.centers_in_ego`."""
    return dataset_overlap.centers_in_ego(boxes["translation"], boxes["sample"], ego_rotation, ego_translation)


def overlap_bits(boxes: np.ndarray, centers_ego: np.ndarray, rigs: Sequence[CameraRig],
                 rig_of_sample: np.ndarray) -> OverlapBits:
    """The overlap pairs of each box of a box table, from its sample's rig (-1: no camera, no
    pair): :func:`sianms_cli.nuscenes.overlap.rig_overlap_bits`."""
    box_rig = rig_of_sample[boxes["sample"]] if len(boxes) else np.zeros(0, np.int64)
    return dataset_overlap.rig_overlap_bits(centers_ego, box_rig, rigs)


def _canonical_pair(name: str, pair_names: Sequence[str]) -> str | None:
    cameras = name[len(PAIR_PREFIX):].split("|")
    if len(cameras) != 2:
        return None
    for known in pair_names:
        if set(known.split("|")) == set(cameras) and cameras[0] != cameras[1]:
            return known
    return None


def resolve_regions(requested: Iterable[str], pair_names: Sequence[str]) -> list[str]:
    """Validated, canonical region names: ``overlap:*`` expanded, pairs spelt as in the rigs,
    duplicates dropped, order kept. SianmsError lists the valid names for an unknown one."""
    resolved: list[str] = []
    for raw in requested:
        name = raw.strip()
        if name in (ALL, OVERLAP, NON_OVERLAP):
            names = [name]
        elif name == EVERY_PAIR:
            names = [PAIR_PREFIX + pair for pair in pair_names]
        elif name.startswith(PAIR_PREFIX) and (pair := _canonical_pair(name, pair_names)):
            names = [PAIR_PREFIX + pair]
        else:
            pairs = ", ".join(PAIR_PREFIX + pair for pair in pair_names) or "none (no camera pairs)"
            raise SianmsError(f"unknown region '{name}'; regions: {ALL}, {OVERLAP}, {NON_OVERLAP}, "
                              f"{EVERY_PAIR}, or one pair: {pairs}")
        resolved.extend(n for n in names if n not in resolved)
    if not resolved:
        raise SianmsError("no region given")
    return resolved


def needs_overlap(regions: Iterable[str]) -> bool:
    """Whether any of the (raw) region names needs the camera geometry."""
    return any(region.strip() != ALL for region in regions)


def region_mask(region: str, overlap: OverlapBits | None, count: int) -> np.ndarray:
    """(count,) bool: the boxes in a canonical region (see :func:`resolve_regions`)."""
    if region == ALL:
        return np.ones(count, dtype=bool)
    assert overlap is not None and len(overlap.bits) == count, region
    if region == OVERLAP:
        return overlap.bits != 0
    if region == NON_OVERLAP:
        return overlap.bits == 0
    bit = np.uint64(1 << overlap.pair_names.index(region[len(PAIR_PREFIX):]))
    return (overlap.bits & bit) != 0
