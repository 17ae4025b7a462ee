"""Which contiguous camera pairs see each annotated box: THE overlap rule applied to a dataset.

One function decides it for every consumer, so they cannot drift apart: `sianms prepare`
(the ``overlap_pairs`` of each detection and the pairs' ``center_in_overlap``), `sianms info`
(the cars' overlap share) and `sianms metrics` (the ``overlap`` regions). For a box of a sample:

- the rig is the sample's (:func:`sianms_cli.nuscenes.sample_rigs.sample_rigs`: the calibrated
  cameras of its key frames);
- its centre goes into the ego frame with the ego pose of the sample's LIDAR_TOP key frame
  (the pose the devkit measures ranges from);
- :meth:`sianms_cli.geometry.camera_ring.CameraRig.overlap_pairs` is the rule: the centre, in front
  of both cameras, projects inside both images of a contiguous pair.

A sample without camera key frames or without a LIDAR_TOP key frame has no overlap.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from sianms_cli.errors import SianmsError
from sianms_cli.geometry.quaternion import quat_to_matrix
from sianms_cli.geometry.camera_ring import CameraRig
from sianms_cli.nuscenes.keyframes import keyframe_rows, sensor_records
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.sample_rigs import sample_rigs

LIDAR_CHANNEL = "LIDAR_TOP"
MAX_PAIRS = 64  # one bit each in a uint64


@dataclass(frozen=True, eq=False)
class OverlapBits:
    """Which contiguous camera pairs see each box: bit k of ``bits`` is pair ``pair_names[k]``.

    ``pair_names`` is the union of the pair names of the rigs involved, in first-seen order
    (``CAM_FRONT|CAM_FRONT_RIGHT`` first on a nuScenes rig).
    """

    pair_names: tuple[str, ...]
    bits: np.ndarray

    def pairs(self, names: Sequence[str]) -> np.ndarray:
        """(N, len(names)) bool: whether each box is in the overlap of each named pair (a name
        that is not in ``pair_names`` is never set)."""
        known = np.array([name in self.pair_names for name in names], dtype=bool)
        index = np.array([self.pair_names.index(name) if name in self.pair_names else 0 for name in names],
                         dtype=np.uint64)
        return ((self.bits[:, None] >> index[None, :]) & np.uint64(1)).astype(bool) & known[None, :]


def lidar_ego_poses(db: NuScenesDB, sample_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ego pose of each sample's LIDAR_TOP key frame (a later key frame wins, as the devkit).

    Returns:
        ``(rotation (S, 4) w,x,y,z, translation (S, 3) m, found (S,) bool)``; the identity
        pose where a sample has no LIDAR_TOP key frame (``found`` false), so every pose
        can be applied.
    """
    rows = keyframe_rows(db, sample_rows, [LIDAR_CHANNEL])[:, 0]
    records = sensor_records(db, rows)
    found = rows >= 0
    rotation = np.where(found[:, None], records.ego_rotation, [1.0, 0.0, 0.0, 0.0])
    return rotation, np.where(found[:, None], records.ego_translation, 0.0), found


def centers_in_ego(centers: np.ndarray, box_sample: np.ndarray, ego_rotation: np.ndarray,
                   ego_translation: np.ndarray) -> np.ndarray:
    """(N, 3) box centres in the ego frame of their sample: ``R_ego^T (p - t_ego)``.

    Args:
        centers: (N, 3) global box centres.
        box_sample: (N,) int64 each box's sample, an index into the pose arrays.
        ego_rotation, ego_translation: (S, 4), (S, 3) ego poses of the samples.
    """
    rotations = quat_to_matrix(ego_rotation)
    offset = np.asarray(centers, dtype=np.float64).reshape(-1, 3) - ego_translation[box_sample]
    return np.einsum("nji,nj->ni", rotations[box_sample], offset)


def rig_overlap_bits(centers_ego: np.ndarray, box_rig: np.ndarray, rigs: Sequence[CameraRig]) -> OverlapBits:
    """The overlap pairs of each box by THE rule of its rig.

    Args:
        centers_ego: (N, 3) box centres in the ego frame of their sample.
        box_rig: (N,) int64 index of each box's rig in ``rigs``; -1: no rig, no pair.
        rigs: the distinct rigs.
    """
    names: list[str] = []
    for rig in rigs:
        names.extend(name for name in rig.pair_names if name not in names)
    if len(names) > MAX_PAIRS:
        raise SianmsError(f"{len(names)} distinct camera pairs; at most {MAX_PAIRS} are supported")
    bits = np.zeros(len(box_rig), dtype=np.uint64)
    for r, rig in enumerate(rigs):
        rows = np.flatnonzero(box_rig == r)
        if len(rows) == 0 or not rig.pair_names:
            continue
        seen = rig.overlap_pairs(centers_ego[rows])
        weights = np.array([1 << names.index(name) for name in rig.pair_names], dtype=np.uint64)
        bits[rows] = np.bitwise_or.reduce(np.where(seen, weights, np.uint64(0)), axis=1)
    return OverlapBits(tuple(names), bits)


def box_overlap_pairs(db: NuScenesDB, sample_tokens: Sequence[str] | np.ndarray, box_sample: np.ndarray,
                      centers: np.ndarray) -> OverlapBits:
    """THE overlap pairs of annotated boxes (see the module docstring).

    Args:
        db: the loaded dataset.
        sample_tokens: S samples (DataFormatError for an unknown one).
        box_sample: (N,) int64 each box's sample, an index into ``sample_tokens``.
        centers: (N, 3) global box centres.
    """
    box_sample = np.asarray(box_sample, dtype=np.int64).reshape(-1)
    rigs, rig_of_sample = sample_rigs(db, sample_tokens)
    rotation, translation, found = lidar_ego_poses(db, db.table("sample").indices(list(sample_tokens)))
    centers_ego = centers_in_ego(centers, box_sample, rotation, translation)
    box_rig = np.where(found[box_sample], rig_of_sample[box_sample], -1)
    return rig_overlap_bits(centers_ego, box_rig, rigs)
