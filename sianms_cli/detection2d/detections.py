"""The 2D detections of one camera image as aligned arrays."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Detections2D:
    """N detections in one image.

    Attributes:
        boxes: (N, 4) float64 [x1, y1, x2, y2] pixels of the original image.
        scores: (N,) float64 confidences in [0, 1].
        classes: (N,) str detection classes.
    """

    boxes: np.ndarray
    scores: np.ndarray
    classes: np.ndarray

    def __len__(self) -> int:
        return len(self.scores)

    @staticmethod
    def empty() -> Detections2D:
        return Detections2D(np.zeros((0, 4)), np.zeros(0), np.zeros(0, dtype="<U1"))

    @staticmethod
    def concatenate(parts: list[Detections2D]) -> Detections2D:
        parts = [part for part in parts if len(part)]
        if not parts:
            return Detections2D.empty()
        return Detections2D(
            np.concatenate([p.boxes for p in parts]).reshape(-1, 4),
            np.concatenate([p.scores for p in parts]),
            np.concatenate([np.asarray(p.classes, dtype=str) for p in parts]),
        )

    def sorted_by_score(self) -> Detections2D:
        """Descending score; ties keep their order (stable)."""
        order = np.argsort(-self.scores, kind="stable")
        return Detections2D(self.boxes[order], self.scores[order], self.classes[order])
