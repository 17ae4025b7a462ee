"""Detection classes of nuScenes categories (the devkit's ``category_to_detection_name``)."""

from __future__ import annotations

import numpy as np

from sianms_cli.errors import SianmsError

CATEGORY_TO_CLASS: dict[str, str] = {
    "movable_object.barrier": "barrier",
    "vehicle.bicycle": "bicycle",
    "vehicle.bus.bendy": "bus",
    "vehicle.bus.rigid": "bus",
    "vehicle.car": "car",
    "vehicle.construction": "construction_vehicle",
    "vehicle.motorcycle": "motorcycle",
    "human.pedestrian.adult": "pedestrian",
    "human.pedestrian.child": "pedestrian",
    "human.pedestrian.construction_worker": "pedestrian",
    "human.pedestrian.police_officer": "pedestrian",
    "movable_object.trafficcone": "traffic_cone",
    "vehicle.trailer": "trailer",
    "vehicle.truck": "truck",
}

DETECTION_CLASSES: tuple[str, ...] = (
    "car", "truck", "bus", "trailer", "construction_vehicle", "pedestrian", "motorcycle",
    "bicycle", "traffic_cone", "barrier",
)

PAPER_CLASSES: tuple[str, ...] = ("car", "pedestrian", "bicycle")
"""The paper's three classes (Car, Pedestrian, Cyclist; §V), as nuScenes detection classes."""


def detection_classes_of(category_names: np.ndarray) -> np.ndarray:
    """(N,) str detection class of each category name; ``""`` for ignored categories."""
    names = np.asarray(category_names, dtype=str).reshape(-1)
    return np.array([CATEGORY_TO_CLASS.get(str(name), "") for name in names], dtype=str)


def check_classes(classes: tuple[str, ...] | list[str]) -> tuple[str, ...]:
    """Validated, de-duplicated class names in the given order; SianmsError for an unknown one."""
    out: list[str] = []
    for name in classes:
        if name not in DETECTION_CLASSES:
            raise SianmsError(
                f"unknown detection class '{name}'; expected some of {', '.join(DETECTION_CLASSES)}"
            )
        if name not in out:
            out.append(name)
    if not out:
        raise SianmsError("at least one detection class is needed")
    return tuple(out)
