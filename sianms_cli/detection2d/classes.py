"""Detection classes of nuScenes categories (the devkit's ``category_to_detection_name``)."""

from __future__ import annotations

import numpy as np

from sianms_cli.errors import SianmsError
from sianms_cli.nuscenes.classes import CATEGORY_TO_DETECTION, DETECTION_CLASSES


def detection_classes_of(category_names: np.ndarray) -> np.ndarray:
    """(N,) str detection class of each category name; ``""`` for ignored categories."""
    names = np.asarray(category_names, dtype=str).reshape(-1)
    return np.array([CATEGORY_TO_DETECTION.get(str(name), "") for name in names], dtype=str)


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
