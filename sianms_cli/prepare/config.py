"""What `sianms prepare` computes: the frozen, validated config whose fields decide the bytes written."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

from sianms_cli.detection2d.backbones import BACKBONES
from sianms_cli.detection2d.classes import check_classes
from sianms_cli.detection2d.detectors import parse_detector
from sianms_cli.errors import SianmsError, check_seed
from sianms_cli.io import sha256_of
from sianms_cli.nuscenes.classes import PAPER_CLASSES
from sianms_cli.nuscenes.tables import check_version_name

MAX_SAMPLING_RATIO = 16  # samples per bin side: detectron2 uses 0 (adaptive) or 2; the cost grows with its square
MAX_ROI_SIZE = 64  # pixels a side: ROI Align pools 7 or 14 in practice; beyond this a feature row passes 4 MB
MAX_SWEEPS = 100  # 5 s of 20 Hz LiDAR (detectors stack about 10, 0.5 s): more is a typo that exhausts memory


@dataclass(frozen=True)
class PrepareConfig:
    """What `sianms prepare` computes. Only these fields affect the bytes written."""

    dataroot: str
    version: str
    split: str
    detector: str = "simulated"  # "simulated" or "file:PATH" (.parquet or .json)
    backbone: str = "tiny"  # "tiny" or "resnet50-c4"
    weights: str | None = None  # local checkpoint for resnet50-c4
    classes: tuple[str, ...] = PAPER_CLASSES
    seed: int = 0
    iou_threshold: float = 0.5  # association with the projected ground truth
    fill_missed: bool | None = None  # None: on for training splits (name contains "train")
    roi_size: int = 7
    sampling_ratio: int = 0  # <= 0: adaptive, as detectron2's C4 head
    sweeps: int = 0  # earlier LiDAR sweeps added to each key frame's points
    min_depth: float = 1.0  # frustum depth window, metres
    max_depth: float | None = None

    def __post_init__(self) -> None:
        check_version_name(self.version)
        object.__setattr__(self, "classes", check_classes(self.classes))
        parse_detector(self.detector)
        if self.backbone not in BACKBONES:
            raise SianmsError(f"unknown backbone '{self.backbone}'; expected one of {', '.join(BACKBONES)}")
        if self.sampling_ratio > MAX_SAMPLING_RATIO:
            raise SianmsError(f"--sampling-ratio must be at most {MAX_SAMPLING_RATIO} (<= 0: adaptive), "
                              f"got {self.sampling_ratio}")
        if not 1 <= self.roi_size <= MAX_ROI_SIZE:
            raise SianmsError(f"--roi-size must be between 1 and {MAX_ROI_SIZE}, got {self.roi_size}")
        check_seed(self.seed)
        if not 0 <= self.sweeps <= MAX_SWEEPS:
            raise SianmsError(f"--sweeps must be in [0, {MAX_SWEEPS}], got {self.sweeps}")
        if not 0 < self.iou_threshold <= 1:
            raise SianmsError(f"--iou-threshold must be in (0, 1], got {self.iou_threshold}")
        if not (math.isfinite(self.min_depth) and self.min_depth >= 0):
            raise SianmsError(f"--min-depth must be a finite number >= 0, got {self.min_depth}")
        if self.max_depth is not None and not (math.isfinite(self.max_depth) and self.max_depth > self.min_depth):
            raise SianmsError(f"--max-depth must be a finite number greater than --min-depth ({self.min_depth}), "
                              f"got {self.max_depth} (leave it out for no limit)")

    @property
    def fills_missed(self) -> bool:
        return ("train" in self.split) if self.fill_missed is None else self.fill_missed

    def resolved(self, dataset_fingerprint: str, split_scenes: list[str]) -> dict[str, Any]:
        """The config as written to the manifest: derived values filled in, inputs fingerprinted.

        Inputs enter by content, not by path: the dataset by ``dataset_fingerprint``, the split
        by its scenes, a detections file and backbone weights by their SHA-256. So a cache stays
        valid when its inputs are moved, and becomes stale when one of them changes.
        """
        data = asdict(self)
        del data["dataroot"]
        data["classes"] = list(self.classes)
        data["fill_missed"] = self.fills_missed
        data["dataset_sha256"] = dataset_fingerprint
        data["split_scenes"] = list(split_scenes)
        detections_file = parse_detector(self.detector).file
        if detections_file is not None:
            data["detector"] = "file"
            data["detector_sha256"] = sha256_of(detections_file)
        data["weights"] = None if self.weights is None else "sha256:" + sha256_of(self.weights)
        return data
