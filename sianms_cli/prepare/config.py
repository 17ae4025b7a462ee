"""What `sianms prepare` computes: the frozen, validated config whose fields decide the bytes written."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from sianms_cli.detection2d.backbones import BACKBONES
from sianms_cli.detection2d.classes import check_classes
from sianms_cli.errors import SianmsError
from sianms_cli.io import sha256_of
from sianms_cli.nuscenes.classes import PAPER_CLASSES


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
        object.__setattr__(self, "classes", check_classes(self.classes))
        if not (self.detector == "simulated" or self.detector.startswith("file:")):
            raise SianmsError(f"unknown detector '{self.detector}'; expected 'simulated' or 'file:PATH'")
        if self.backbone not in BACKBONES:
            raise SianmsError(f"unknown backbone '{self.backbone}'; expected one of {', '.join(BACKBONES)}")
        if self.roi_size < 1:
            raise SianmsError(f"--roi-size must be at least 1, got {self.roi_size}")
        if self.sweeps < 0:
            raise SianmsError(f"--sweeps must be >= 0, got {self.sweeps}")
        if not 0 < self.iou_threshold <= 1:
            raise SianmsError(f"--iou-threshold must be in (0, 1], got {self.iou_threshold}")

    @property
    def fills_missed(self) -> bool:
        return ("train" in self.split) if self.fill_missed is None else self.fill_missed

    def resolved(self) -> dict[str, Any]:
        """The config as written to the manifest: derived values filled in, files fingerprinted."""
        data = asdict(self)
        data["classes"] = list(self.classes)
        data["fill_missed"] = self.fills_missed
        data["dataroot"] = str(Path(self.dataroot).resolve())
        if self.detector.startswith("file:"):
            path = Path(self.detector[5:])
            data["detector_sha256"] = sha256_of(path) if path.is_file() else None
        if self.weights is not None and Path(self.weights).is_file():
            data["weights_sha256"] = sha256_of(Path(self.weights))
        return data
