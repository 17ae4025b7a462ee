"""The 2D detections and the 2D ground truth of one camera image, as aligned arrays."""

from __future__ import annotations

from dataclasses import dataclass, fields

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


@dataclass(frozen=True)
class GroundTruth2D:
    """The annotated objects one camera image shows, as the image shows them: N rows.

    What a 2D detector (real or simulated) and the association need of the ground truth, and
    nothing of the 3D boxes it was projected from (that projection lives with `sianms
    prepare`, :mod:`sianms_cli.prepare.ground_truth`).

    Attributes:
        ids: (N,) int64 the caller's id of each object, carried through :meth:`subset`
            (prepare: the annotation's index in its sample).
        boxes: (N, 4) float64 [x1, y1, x2, y2] clipped to the image, pixels.
        classes: (N,) str detection class ("" for categories no detector reports).
        truncation: (N,) share of the unclipped 2D box outside the image, [0, 1].
        occlusion: (N,) share of the 2D box covered by nearer objects, [0, 1].
        distance: (N,) metres from the camera to the object (the detector's range term).
    """

    ids: np.ndarray
    boxes: np.ndarray
    classes: np.ndarray
    truncation: np.ndarray
    occlusion: np.ndarray
    distance: np.ndarray

    def __len__(self) -> int:
        return len(self.ids)

    @property
    def visibility(self) -> np.ndarray:
        """(N,) share of the whole object visible in this image: (1 - truncation)(1 - occlusion)."""
        return (1.0 - self.truncation) * (1.0 - self.occlusion)

    def subset(self, mask: np.ndarray) -> GroundTruth2D:
        """The rows where ``mask`` (bool or indices) selects."""
        return GroundTruth2D(**{field.name: getattr(self, field.name)[mask] for field in fields(self)})
