"""nuScenes detection classes: the devkit's category -> detection class map, as data.

The detection benchmark merges the 23 general categories into 10 classes and ignores the
rest (``category_to_detection_name`` of nuscenes-devkit; docs/metrics.md#what-is-computed).
"""

from __future__ import annotations

CATEGORY_TO_DETECTION: dict[str, str] = {
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
"""Every category not listed here is not evaluated."""

DETECTION_CLASSES: tuple[str, ...] = (
    "car", "truck", "bus", "trailer", "construction_vehicle", "pedestrian", "motorcycle",
    "bicycle", "traffic_cone", "barrier",
)
"""The 10 detection classes in the devkit's order (DETECTION_NAMES)."""

PAPER_CLASSES: tuple[str, ...] = ("car", "pedestrian", "bicycle")
"""The paper's three classes (Car, Pedestrian, Cyclist; its §V) as nuScenes detection classes:
"Cyclist" is not defined in the paper and maps to the devkit's ``bicycle``."""
