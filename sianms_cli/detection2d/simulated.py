"""A simulated 2D detector: projected ground truth turned into what a real detector gives.

Model, per class (:class:`ClassModel`), for each ground-truth box of one image
(docs/methods.md#the-simulated-detector):

- **apparent size** ``h`` = clipped box height rescaled to a 1600-px-wide image (the nuScenes
  camera), so the detector behaves the same whatever resolution the images were stored at;
- **detection probability**
  ``p = max_recall * sigmoid((h - height50) / height_slope) * (1 - occlusion)^occlusion_power
  * (1 - truncation)^truncation_power * exp(-distance / range_m)``;
- **box jitter**: centre shifted by N(0, s·w), N(0, s·h), width and height scaled by
  exp(N(0, s)), with ``s = jitter + jitter_truncation·truncation + jitter_distance·distance/50``;
- **score** ``sigmoid(score_offset + score_gain·v + N(0, score_noise))`` with
  ``v = size term · (1 - occlusion) · sqrt(1 - truncation)``;
- **false positives**: Poisson(``fp_per_image``) boxes per image, log-normal height around
  ``fp_height``, the class's aspect ratio, in the image band where the road scene lies,
  rejected above IoU 0.2 with any ground-truth box; scores Beta(``fp_score_a``, ``fp_score_b``).

Detections below ``score_threshold`` (0.05) are dropped. Every draw comes from the generator
passed in, in a fixed order, so the same generator state gives the same detections.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from sianms_cli.detection2d.association import box_iou
from sianms_cli.detection2d.classes import check_classes
from sianms_cli.detection2d.detections import Detections2D, GroundTruth2D
from sianms_cli.errors import SianmsError
from sianms_cli.nuscenes.classes import PAPER_CLASSES

REFERENCE_WIDTH = 1600.0  # nuScenes camera images are 1600 x 900


@dataclass(frozen=True)
class ClassModel:
    """Per-class parameters of the simulated detector (see the module docstring)."""

    max_recall: float
    height50: float  # px at 1600-px width where the size term is 0.5
    height_slope: float  # px
    occlusion_power: float
    truncation_power: float
    range_m: float
    jitter: float
    jitter_truncation: float
    jitter_distance: float
    score_offset: float
    score_gain: float
    score_noise: float
    fp_per_image: float
    fp_height: float  # px at 1600-px width, median
    aspect: float  # typical width / height of the class's 2D boxes
    fp_score_a: float = 2.0
    fp_score_b: float = 4.0


_VEHICLE = ClassModel(
    max_recall=0.97, height50=20.0, height_slope=5.0, occlusion_power=1.5, truncation_power=0.7,
    range_m=250.0, jitter=0.04, jitter_truncation=0.10, jitter_distance=0.03,
    score_offset=-1.0, score_gain=4.5, score_noise=0.6,
    fp_per_image=0.35, fp_height=45.0, aspect=1.6,
)

DEFAULT_CLASS_MODELS: dict[str, ClassModel] = {
    "car": _VEHICLE,
    "truck": replace(_VEHICLE, max_recall=0.85, score_offset=-1.4, fp_per_image=0.15, aspect=1.4),
    "bus": replace(_VEHICLE, max_recall=0.90, score_offset=-1.2, fp_per_image=0.05, aspect=1.5),
    "motorcycle": replace(_VEHICLE, max_recall=0.80, height50=22.0, score_offset=-1.4,
                          fp_per_image=0.08, aspect=0.9),
    "pedestrian": ClassModel(
        max_recall=0.88, height50=28.0, height_slope=6.0, occlusion_power=1.8, truncation_power=0.9,
        range_m=150.0, jitter=0.05, jitter_truncation=0.12, jitter_distance=0.04,
        score_offset=-1.3, score_gain=4.3, score_noise=0.7,
        fp_per_image=0.35, fp_height=50.0, aspect=0.4,
    ),
    "bicycle": ClassModel(
        max_recall=0.82, height50=26.0, height_slope=6.0, occlusion_power=1.8, truncation_power=0.9,
        range_m=150.0, jitter=0.06, jitter_truncation=0.12, jitter_distance=0.04,
        score_offset=-1.5, score_gain=4.3, score_noise=0.7,
        fp_per_image=0.12, fp_height=40.0, aspect=0.9,
    ),
}
"""Classes a COCO-trained detector knows (COCO car, truck, bus, motorcycle, person, bicycle)."""


@dataclass(frozen=True)
class SimulatedDetectorConfig:
    """Which classes the simulated detector reports, and its per-class models."""

    classes: tuple[str, ...] = PAPER_CLASSES
    score_threshold: float = 0.05
    models: dict[str, ClassModel] = field(default_factory=lambda: dict(DEFAULT_CLASS_MODELS))

    def __post_init__(self) -> None:
        classes = check_classes(self.classes)
        missing = [name for name in classes if name not in self.models]
        if missing:
            raise SianmsError(
                f"the simulated detector has no model for class '{missing[0]}' (COCO has no such "
                f"class); it simulates {', '.join(self.models)}"
            )
        object.__setattr__(self, "classes", classes)


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


def detection_probability(
    model: ClassModel, height_ref: np.ndarray, occlusion: np.ndarray, truncation: np.ndarray,
    distance: np.ndarray,
) -> np.ndarray:
    """(N,) probability that the detector finds each object (see the module docstring).

    Args:
        model: the class's parameters.
        height_ref: (N,) clipped 2D box height in pixels of a 1600-px-wide image.
        occlusion, truncation: (N,) shares in [0, 1].
        distance: (N,) metres from the camera.
    """
    size = _sigmoid((np.asarray(height_ref) - model.height50) / model.height_slope)
    return (
        model.max_recall * size
        * np.clip(1.0 - np.asarray(occlusion), 0, 1) ** model.occlusion_power
        * np.clip(1.0 - np.asarray(truncation), 0, 1) ** model.truncation_power
        * np.exp(-np.asarray(distance) / model.range_m)
    )


def simulate_detections(
    gt: GroundTruth2D,
    image_size: tuple[int, int],
    rng: np.random.Generator,
    config: SimulatedDetectorConfig = SimulatedDetectorConfig(),
) -> Detections2D:
    """Detections of one image from its projected ground truth.

    Args:
        gt: the image's ground truth (all classes; only ``config.classes`` are detected, but
            every box counts as foreground when placing false positives).
        image_size: (W, H) pixels.
        rng: the generator all draws come from.
        config: classes and models.

    Returns:
        Detections sorted by descending score.
    """
    width, height = float(image_size[0]), float(image_size[1])
    scale = REFERENCE_WIDTH / width
    parts = []
    for name in config.classes:
        model = config.models[name]
        mine = gt.subset(gt.classes == name)
        parts.append(_true_detections(mine, model, name, scale, width, height, rng))
        parts.append(_false_positives(gt.boxes, model, name, scale, width, height, rng))
    detections = Detections2D.concatenate(parts)
    keep = detections.scores >= config.score_threshold
    return Detections2D(detections.boxes[keep], detections.scores[keep], detections.classes[keep]).sorted_by_score()


@dataclass(frozen=True)
class SimulatedDetector:
    """The simulated detector as a :class:`~sianms_cli.detection2d.detectors.Detector`."""

    config: SimulatedDetectorConfig = field(default_factory=SimulatedDetectorConfig)

    def detections(self, sample_data_token: str, ground_truth: GroundTruth2D, image_size: tuple[int, int],
                   rng: np.random.Generator) -> Detections2D:
        """The image's detections, drawn from ``rng`` (the token plays no part)."""
        return simulate_detections(ground_truth, image_size, rng, self.config)


def _true_detections(
    gt: GroundTruth2D, model: ClassModel, name: str, scale: float, width: float, height: float,
    rng: np.random.Generator,
) -> Detections2D:
    count = len(gt)
    boxes = gt.boxes
    box_w = boxes[:, 2] - boxes[:, 0]
    box_h = boxes[:, 3] - boxes[:, 1]
    height_ref = box_h * scale
    probability = detection_probability(model, height_ref, gt.occlusion, gt.truncation, gt.distance)
    found = rng.random(count) < probability
    noise = rng.standard_normal((count, 4))
    score_noise = rng.standard_normal(count)
    sigma = model.jitter + model.jitter_truncation * gt.truncation + model.jitter_distance * gt.distance / 50.0
    cx = 0.5 * (boxes[:, 0] + boxes[:, 2]) + noise[:, 0] * sigma * box_w
    cy = 0.5 * (boxes[:, 1] + boxes[:, 3]) + noise[:, 1] * sigma * box_h
    new_w = box_w * np.exp(noise[:, 2] * sigma)
    new_h = box_h * np.exp(noise[:, 3] * sigma)
    jittered = _clip(np.stack([cx - new_w / 2, cy - new_h / 2, cx + new_w / 2, cy + new_h / 2], axis=1), width, height)
    size_term = _sigmoid((height_ref - model.height50) / model.height_slope)
    visible = size_term * (1.0 - gt.occlusion) * np.sqrt(np.clip(1.0 - gt.truncation, 0, 1))
    scores = _sigmoid(model.score_offset + model.score_gain * visible + model.score_noise * score_noise)
    keep = found & (jittered[:, 2] > jittered[:, 0]) & (jittered[:, 3] > jittered[:, 1])
    return Detections2D(jittered[keep], scores[keep], np.full(int(keep.sum()), name))


def _false_positives(
    gt_boxes: np.ndarray, model: ClassModel, name: str, scale: float, width: float, height: float,
    rng: np.random.Generator, tries: int = 5,
) -> Detections2D:
    count = int(rng.poisson(model.fp_per_image))
    if count == 0:
        return Detections2D.empty()
    draws = tries * count
    box_h = model.fp_height / scale * np.exp(0.5 * rng.standard_normal(draws))
    box_w = box_h * model.aspect * np.exp(0.2 * rng.standard_normal(draws))
    cx = rng.random(draws) * width
    cy = (0.35 + 0.4 * rng.random(draws)) * height
    scores = rng.beta(model.fp_score_a, model.fp_score_b, draws)
    boxes = _clip(np.stack([cx - box_w / 2, cy - box_h / 2, cx + box_w / 2, cy + box_h / 2], axis=1), width, height)
    background = (boxes[:, 2] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 1])
    if len(gt_boxes):
        background &= box_iou(boxes, gt_boxes).max(axis=1) <= 0.2
    chosen = np.flatnonzero(background)[:count]
    return Detections2D(boxes[chosen], scores[chosen], np.full(len(chosen), name))


def _clip(boxes: np.ndarray, width: float, height: float) -> np.ndarray:
    boxes = boxes.copy()
    boxes[:, [0, 2]] = np.clip(boxes[:, [0, 2]], 0.0, width)
    boxes[:, [1, 3]] = np.clip(boxes[:, [1, 3]], 0.0, height)
    return boxes
