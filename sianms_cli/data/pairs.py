"""Pairs of detections of one instance in two contiguous cameras (paper §IV-B)."""

from __future__ import annotations

import numpy as np


def contiguous_pairs(
    camera_index: np.ndarray,
    instance_tokens: np.ndarray,
    rig_pairs: tuple[tuple[int, int], ...],
) -> np.ndarray:
    """Which detections form a (reference, positive) pair.

    A pair is two detections associated with the same instance ("" = none, never paired) in
    the two cameras of a contiguous pair of the rig; the reference is in the first camera of
    the pair, the positive in the second. Cameras that are not contiguous never pair.

    Built on a dense (instance x camera) table of detection indices: association is
    one-to-one per image, so each (instance, camera) holds at most one detection.

    Args:
        camera_index: (D,) rig camera index of each detection, in [0, C).
        instance_tokens: (D,) str associated instance of each detection, "" for none.
        rig_pairs: the rig's contiguous pairs (``CameraRig.contiguous_pairs``).

    Returns:
        (R, 3) int64 rows (pair number, reference detection, positive detection), sorted.
    """
    camera_index = np.asarray(camera_index, dtype=np.int64).reshape(-1)
    instance_tokens = np.asarray(instance_tokens, dtype=str).reshape(-1)
    pairs = np.asarray(rig_pairs, dtype=np.int64).reshape(-1, 2)
    detections = np.flatnonzero(instance_tokens != "")
    if len(detections) == 0 or len(pairs) == 0:
        return np.zeros((0, 3), dtype=np.int64)
    instances, instance = np.unique(instance_tokens[detections], return_inverse=True)
    cameras = int(max(camera_index[detections].max(), pairs.max())) + 1
    where = np.full((len(instances), cameras), -1, dtype=np.int64)
    where[instance, camera_index[detections]] = detections
    assert (where >= 0).sum() == len(detections), "two detections of one instance in one camera"
    reference, positive = where[:, pairs[:, 0]], where[:, pairs[:, 1]]  # (instances, pairs)
    found = (reference >= 0) & (positive >= 0)
    rows = np.stack([np.broadcast_to(np.arange(len(pairs)), found.shape)[found], reference[found], positive[found]],
                    axis=1)
    return rows[np.lexsort(rows.T[::-1])]
