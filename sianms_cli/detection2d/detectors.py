"""What a 2D detector is to `sianms prepare`, and the one place a ``--detector`` value becomes one.

A :class:`Detector` gives the detections of one camera image. The simulated detector draws
them from the image's projected ground truth and a generator; an external file looks them
up by the image's sample_data token. Both take the same arguments so the per-camera code
never asks which one it has.

``--detector`` values: ``simulated``, or ``file:PATH`` with PATH a ``.parquet`` or ``.json``
file of 2D detections (:mod:`sianms_cli.detection2d.external`). :func:`parse_detector`
checks the value without reading anything (a config validates with it);
:func:`build_detector` makes the detector, reading and validating the file.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from sianms_cli.detection2d.detections import Detections2D, GroundTruth2D
from sianms_cli.detection2d.external import ExternalDetections
from sianms_cli.detection2d.simulated import SimulatedDetector, SimulatedDetectorConfig
from sianms_cli.errors import SianmsError
from sianms_cli.io import expand_home
from sianms_cli.nuscenes.loader import NuScenesDB

SIMULATED = "simulated"
FILE_PREFIX = "file:"


class Detector(Protocol):
    """A source of 2D detections, one camera image at a time."""

    def detections(self, sample_data_token: str, ground_truth: GroundTruth2D, image_size: tuple[int, int],
                   rng: np.random.Generator) -> Detections2D:
        """The detections of one image, sorted by descending score.

        Args:
            sample_data_token: the image's camera sample_data.
            ground_truth: the objects the image shows (all classes).
            image_size: (W, H) pixels.
            rng: the generator every random draw comes from, seeded per image by the caller.
        """
        ...


@dataclass(frozen=True)
class DetectorSpec:
    """A parsed ``--detector`` value: ``file`` is None for the simulated detector."""

    file: Path | None = None


def parse_detector(text: str) -> DetectorSpec:
    """Parse a ``--detector`` value; SianmsError naming the flag for anything else."""
    if text == SIMULATED:
        return DetectorSpec()
    if text.startswith(FILE_PREFIX) and len(text) > len(FILE_PREFIX):
        return DetectorSpec(expand_home(Path(text[len(FILE_PREFIX):])))  # the shell leaves a ~ after file: as it is
    raise SianmsError(f"unknown detector '{text}'; --detector takes '{SIMULATED}' or '{FILE_PREFIX}PATH' "
                      "(a .parquet or .json file of 2D detections)")


def build_detector(text: str, db: NuScenesDB, classes: tuple[str, ...]) -> Detector:
    """The detector of a ``--detector`` value, reporting ``classes``.

    A file is read and checked against ``db`` here (DataFormatError naming the file and
    the first bad row), so a bad file fails before anything is written.
    """
    spec = parse_detector(text)
    if spec.file is not None:
        return ExternalDetections(spec.file, db, classes)
    return SimulatedDetector(SimulatedDetectorConfig(classes=classes))
