"""Every kind of object the synthetic world holds, and the parts of one of them."""

from __future__ import annotations

import numpy as np

from sianms_cli.synth import people, shapes, vehicles
from sianms_cli.synth.appearance import CLUTTER_KINDS, Appearance
from sianms_cli.synth.shapes import Builder, Parts

_BUILDERS = {**vehicles.BUILDERS, **people.BUILDERS, **shapes.BUILDERS}

KINDS = ("car", "truck", "bus", "trailer", "construction", "pedestrian", "bicycle", "motorcycle", "barrier",
         "traffic_cone", "building") + CLUTTER_KINDS


def object_parts(kind: str, size_wlh, appearance: Appearance) -> Parts:
    """Parts of one object in its local frame.

    kind: one of `KINDS`; size_wlh (3,) box width, length, height in metres (nuScenes
    order); appearance: the object's look from `sample_appearance(kind, ...)`. Returns parts
    with owner 0 and yaw 0 whose union's bounding box is exactly the box
    [-l/2, l/2] x [-w/2, w/2] x [-h/2, h/2]. Raises ValueError for an unknown kind or a
    non-positive size.
    """
    if kind not in _BUILDERS:
        raise ValueError(f"unknown object kind {kind!r}; expected one of {KINDS}")
    size = np.asarray(size_wlh, np.float64).reshape(3)
    if not np.all(size > 0):
        raise ValueError(f"object size must be positive, got {size.tolist()}")
    w, l, h = (float(v) for v in size)
    b = Builder()
    _BUILDERS[kind](b, w, l, h, appearance)
    return b.fitted(size)
