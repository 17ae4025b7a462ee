"""Frustum PointNets inference: frustums in, global boxes out (docs/methods.md#frustum-pointnets-inference).

A frustum is a set of points in its frustum frame (a camera frame rotated about y by
``rot_angle``). Each is sampled to the trained number of points, uniformly with replacement;
the sampling and the masking draw from generators seeded by the evaluation's seed and the
call's key. One call per sample and kind, frustums in a fixed order, so a sample's boxes are
the same whichever worker or run computes them (resume equality).

The box comes back in the frustum frame as (centre, heading ``ry``, (l, w, h)); it is rotated
back by ``-rot_angle`` into the camera frame (heading ``ry + rot_angle``), then moved to the
global frame, where it is made upright: its yaw is that of the length axis
``(cos ry, 0, -sin ry)`` seen from above. Sizes leave as nuScenes' (w, l, h); a size cluster
plus its residual can come out negative from an undertrained network, and such an extent is
clamped to 1 cm (the devkit refuses a box without a positive size; ASE then shows the error).
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from sianms_cli.data.frustum_dataset import INTENSITY_SCALE
from sianms_cli.errors import DataFormatError
from sianms_cli.geometry.frustum import rotate_from_frustum
from sianms_cli.geometry.quaternion import yaw_to_quat

if TYPE_CHECKING:
    from sianms_cli.training.run import Checkpoint

BATCH = 64  # frustums per forward pass: memory stays small at 1,024 points
MIN_EXTENT = 0.01  # metres: an extent the network predicts <= 0 is clamped here, so the devkit accepts the box


@dataclass(frozen=True, eq=False)
class GlobalBoxes:
    """N upright boxes in the global frame.

    Attributes:
        translation: (N, 3) centres, metres; size: (N, 3) (w, l, h), metres;
        yaw: (N,) radians, counter-clockwise from global +x; rotation: (N, 4) quaternions.
    """

    translation: np.ndarray
    size: np.ndarray
    yaw: np.ndarray

    @property
    def rotation(self) -> np.ndarray:
        return yaw_to_quat(self.yaw)

    def __len__(self) -> int:
        return len(self.yaw)


def _checked_classes(path: Path, classes: Any, mean_sizes: Any) -> tuple[tuple[str, ...], np.ndarray]:
    """A checkpoint's classes (distinct names) and their size clusters ((K, 3) finite, > 0 metres),
    one per class: what the one-hot vector and the size head are built from."""
    if not (isinstance(classes, (list, tuple)) and classes and all(isinstance(name, str) for name in classes)
            and len(set(classes)) == len(classes)):
        raise DataFormatError(path, f"must be a list of distinct class names, got {classes!r}",
                              field="extra.classes")
    try:
        sizes = np.asarray(mean_sizes, dtype=np.float32)
    except (TypeError, ValueError):
        sizes = np.zeros((0,), dtype=np.float32)
    if sizes.shape != (len(classes), 3) or not (np.isfinite(sizes).all() and (sizes > 0).all()):
        raise DataFormatError(path, f"must be {len(classes)} rows (one per class) of 3 sizes > 0 in metres",
                              field="extra.mean_sizes")
    return tuple(classes), sizes


def _checked_count(path: Path, config: dict[str, Any], key: str) -> int:
    from sianms_cli.training.fpointnet import MAX_POINTS

    value = config.get(key)
    if not (isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= MAX_POINTS):
        raise DataFormatError(path, f"must be a whole number in [1, {MAX_POINTS:,}], got {value!r}",
                              field=f"config.{key}")
    return value


class FPointNetPredictor:
    """A trained Frustum PointNets v1 (a ``sianms train fpointnet`` run) ready to predict boxes.

    Attributes:
        classes: class names in one-hot order; num_points: points per frustum;
        intensity: whether the model reads the intensity channel; min_box_height: the
        training's minimum 2-D box height (pixels), which inference applies too (the original
        drops smaller detections before F-PointNets).
    """

    def __init__(self, checkpoint: Checkpoint, path: Path, device: str = "cpu") -> None:
        """The model of a ``fpointnet`` checkpoint read from ``path`` (named in errors)."""
        import torch

        from sianms_cli.models.fpointnet import FPointNetV1
        from sianms_cli.training.run import load_state

        config, extra = checkpoint.config, checkpoint.extra
        for key in ("classes", "mean_sizes"):
            if key not in extra:
                raise DataFormatError(path, "the checkpoint lacks what inference needs", field=f"extra.{key}")
        classes, mean_sizes = _checked_classes(path, extra["classes"], extra["mean_sizes"])
        self.path = path
        self.classes: tuple[str, ...] = classes
        self.num_points = _checked_count(path, config, "num_points")
        self.intensity = bool(config["intensity"])
        self.min_box_height = float(config["min_box_height"])
        self.device = torch.device(device)
        self.model = FPointNetV1(torch.as_tensor(mean_sizes), 4 if self.intensity else 3,
                                 num_object_points=_checked_count(path, config, "num_object_points")).to(self.device)
        load_state(self.model, checkpoint.model, path)
        self.model.eval()

    def predict(self, points: np.ndarray, offsets: np.ndarray, class_names: Sequence[str] | np.ndarray, key: str,
                seed: int) -> dict[str, np.ndarray]:
        """Boxes of frustums in their own frames.

        Args:
            points: (M, 4) x, y, z (each in its frustum's frame, metres) and raw intensity
                (0-255, as the cache stores it), the frustums one after the other.
            offsets: (F + 1,) frustum f is ``points[offsets[f]:offsets[f + 1]]``; none empty.
            class_names: F classes, each one of :attr:`classes` (the one-hot vector).
            key: names this call (with ``seed``, its random draws).
            seed: the evaluation's seed.

        Returns:
            ``center`` (F, 3), ``heading`` (F,), ``lwh`` (F, 3) (l, w, h) float64, and
            ``object_points`` (F,) int64, the points the model segmented as object.
        """
        import torch

        from sianms_cli.training.fpointnet import predict

        count = len(offsets) - 1
        out = {"center": np.zeros((count, 3)), "heading": np.zeros(count), "lwh": np.zeros((count, 3)),
               "object_points": np.zeros(count, dtype=np.int64)}
        if count == 0:
            return out
        draws = np.random.default_rng([seed, zlib.crc32(key.encode())])
        sampled = self._sample(np.asarray(points, dtype=np.float64), np.asarray(offsets, dtype=np.int64), draws)
        index = torch.as_tensor([self.classes.index(name) for name in class_names])
        one_hot = torch.nn.functional.one_hot(index, len(self.classes)).float()
        generator = torch.Generator(device=self.device).manual_seed(int(draws.integers(2**62)))
        with torch.no_grad():
            for start in range(0, count, BATCH):
                stop = min(count, start + BATCH)
                tensors = {"points": torch.as_tensor(sampled[start:stop]).to(self.device),
                           "one_hot": one_hot[start:stop].to(self.device)}
                result = predict(self.model, tensors, generator)
                out["center"][start:stop] = result["box_center"].double().cpu().numpy()
                out["heading"][start:stop] = result["box_heading"].double().cpu().numpy()
                out["lwh"][start:stop] = result["box_lwh"].double().cpu().numpy()
                out["object_points"][start:stop] = result["mask"].sum(dim=1).cpu().numpy()
        return out

    def _sample(self, points: np.ndarray, offsets: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(F, num_points, C) float32: each frustum's points drawn uniformly with replacement."""
        count = np.diff(offsets)
        position_in_frustum = np.floor(rng.random((len(count), self.num_points)) * count[:, None]).astype(np.int64)
        index = offsets[:-1, None] + position_in_frustum
        chosen = points[index][..., :4 if self.intensity else 3].astype(np.float32)
        if self.intensity:
            chosen[..., 3] /= INTENSITY_SCALE
        return chosen


def frustum_boxes_to_global(center: np.ndarray, heading: np.ndarray, lwh: np.ndarray, rot_angle: np.ndarray,
                            cam_to_global: np.ndarray) -> GlobalBoxes:
    """Boxes predicted in frustum frames, as upright global boxes (module docstring).

    Args:
        center: (N, 3) frustum-frame centres; heading: (N,) F-PointNets ``ry`` in the frustum
            frame; lwh: (N, 3) (l, w, h); rot_angle: (N,) camera -> frustum angles.
        cam_to_global: (N, 4, 4) each box's camera -> global transform.
    """
    rot_angle = np.asarray(rot_angle, dtype=np.float64)
    center_cam = rotate_from_frustum(center, rot_angle)
    heading_cam = np.asarray(heading, dtype=np.float64) + rot_angle
    length_axis = np.stack([np.cos(heading_cam), np.zeros_like(heading_cam), -np.sin(heading_cam)], axis=1)
    rotation = cam_to_global[:, :3, :3]
    translation = np.einsum("nij,nj->ni", rotation, center_cam) + cam_to_global[:, :3, 3]
    axis_global = np.einsum("nij,nj->ni", rotation, length_axis)
    lwh = np.asarray(lwh, dtype=np.float64).reshape(-1, 3)
    return GlobalBoxes(translation=translation, size=np.maximum(lwh[:, [1, 0, 2]], MIN_EXTENT),
                       yaw=np.arctan2(axis_global[:, 1], axis_global[:, 0]))
