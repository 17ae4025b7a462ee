"""Pairs of detections of one instance in two contiguous cameras (paper §IV-B)."""

from __future__ import annotations

import numpy as np


def contiguous_pairs(
    camera_index: np.ndarray,
    instance_tokens: np.ndarray,
    rig_pairs: tuple[tuple[int, int], ...],
) -> list[tuple[int, int, int]]:
    """Which detections form a (reference, positive) pair.

    A pair is two detections associated with the same instance ("" = none, never paired) in
    the two cameras of a contiguous pair of the rig; the reference is in the first camera of
    the pair, the positive in the second. Cameras that are not contiguous never pair.

    Args:
        camera_index: (D,) rig camera index of each detection.
        instance_tokens: (D,) str associated instance of each detection, "" for none.
        rig_pairs: the rig's contiguous pairs (``CameraRig.contiguous_pairs``).

    Returns:
        (pair number, reference detection, positive detection) rows, sorted.
    """
    camera_index = np.asarray(camera_index, dtype=np.int64)
    instance_tokens = np.asarray(instance_tokens, dtype=str)
    where: dict[tuple[str, int], int] = {}
    for d, (instance, camera) in enumerate(zip(instance_tokens.tolist(), camera_index.tolist())):
        if instance:
            # One detection per (instance, camera): association is one-to-one per image.
            assert (instance, camera) not in where, (instance, camera)
            where[(instance, camera)] = d
    rows = []
    for number, (a, b) in enumerate(rig_pairs):
        for instance in sorted({i for i, _ in where}):
            if (instance, a) in where and (instance, b) in where:
                rows.append((number, where[(instance, a)], where[(instance, b)]))
    return sorted(rows)
