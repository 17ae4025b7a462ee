"""Ground-truth 3D boxes seen by one camera: clipped 2D boxes, truncation and occlusion.

Everything here is computed from geometry alone (the annotated boxes and the camera
calibration), so it runs unchanged on real nuScenes. Camera frame: x right, y down,
z forward, metres; pixels as in :mod:`sianms_cli.geometry.projection`.

Occlusion of a box is the share of its clipped 2D box covered by the clipped 2D boxes of
boxes whose centre is nearer to the camera. The 2D box of a projected cuboid is larger than
its silhouette, so this slightly over-estimates occlusion (a conservative figure); it ignores
occluders that carry no annotation (buildings, unannotated objects).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sianms_cli.geometry.boxes import box_corners
from sianms_cli.geometry.projection import project_boxes_to_image

_MAX_PAIR_SAMPLES = 4_000_000  # bound on the (boxes x samples x boxes) temporary


@dataclass(frozen=True)
class CameraGroundTruth:
    """The annotated boxes of one sample that project into one camera image, N rows.

    Attributes:
        annotation_rows: (N,) int64 rows in the sample_annotation table.
        classes: (N,) str detection class ("" for categories the detector ignores).
        boxes2d: (N, 4) float64 [x1, y1, x2, y2] clipped to the image, pixels.
        truncation: (N,) share of the unclipped 2D box outside the image, [0, 1].
        occlusion: (N,) share of the clipped 2D box covered by nearer boxes, [0, 1].
        distance: (N,) metres from the camera to the box centre.
        center_cam: (N, 3) box centres in the camera frame.
        size: (N, 3) (w, l, h) metres.
        rotation_cam: (N, 4) orientations (w, x, y, z) in the camera frame.
    """

    annotation_rows: np.ndarray
    classes: np.ndarray
    boxes2d: np.ndarray
    truncation: np.ndarray
    occlusion: np.ndarray
    distance: np.ndarray
    center_cam: np.ndarray
    size: np.ndarray
    rotation_cam: np.ndarray

    def __len__(self) -> int:
        return len(self.annotation_rows)

    @property
    def visibility(self) -> np.ndarray:
        """(N,) share of the whole object visible in this image: (1 - truncation)(1 - occlusion)."""
        return (1.0 - self.truncation) * (1.0 - self.occlusion)

    def subset(self, mask: np.ndarray) -> CameraGroundTruth:
        """The rows where ``mask`` (bool or indices) selects."""
        return CameraGroundTruth(**{name: getattr(self, name)[mask] for name in self.__dataclass_fields__})


def occlusion_fractions(
    boxes2d: np.ndarray, distance: np.ndarray, samples_per_side: int = 12
) -> np.ndarray:
    """Share of each 2D box covered by the 2D boxes of nearer objects.

    Each box is sampled on a ``samples_per_side`` x ``samples_per_side`` grid of points at
    the centres of equal cells; a point is covered when it lies inside (bounds inclusive)
    the box of an object with a strictly smaller ``distance``.

    Args:
        boxes2d: (N, 4) [x1, y1, x2, y2] pixels.
        distance: (N,) distances from the camera, metres.
        samples_per_side: grid resolution per box.

    Returns:
        (N,) float64 in [0, 1]; 0 for N = 0 or 1.
    """
    boxes2d = np.asarray(boxes2d, dtype=np.float64).reshape(-1, 4)
    distance = np.asarray(distance, dtype=np.float64).reshape(-1)
    count = len(boxes2d)
    if count < 2:
        return np.zeros(count)
    steps = (np.arange(samples_per_side) + 0.5) / samples_per_side
    width = boxes2d[:, 2] - boxes2d[:, 0]
    height = boxes2d[:, 3] - boxes2d[:, 1]
    xs = boxes2d[:, 0, None] + steps[None, :] * width[:, None]  # (N, k)
    ys = boxes2d[:, 1, None] + steps[None, :] * height[:, None]
    px = np.repeat(xs, samples_per_side, axis=1)  # (N, k*k) x varies slowest
    py = np.tile(ys, (1, samples_per_side))
    nearer = distance[None, :] < distance[:, None]  # (N, N): j nearer than i
    occlusion = np.zeros(count)
    chunk = max(1, _MAX_PAIR_SAMPLES // max(count * samples_per_side**2, 1))
    for start in range(0, count, chunk):
        sl = slice(start, start + chunk)
        inside = (
            (px[sl, :, None] >= boxes2d[None, None, :, 0])
            & (px[sl, :, None] <= boxes2d[None, None, :, 2])
            & (py[sl, :, None] >= boxes2d[None, None, :, 1])
            & (py[sl, :, None] <= boxes2d[None, None, :, 3])
        )
        covered = (inside & nearer[sl, None, :]).any(axis=2)
        occlusion[sl] = covered.mean(axis=1)
    return occlusion


def camera_ground_truth(
    annotation_rows: np.ndarray,
    classes: np.ndarray,
    center_cam: np.ndarray,
    size: np.ndarray,
    rotation_cam: np.ndarray,
    intrinsic: np.ndarray,
    image_size: tuple[int, int],
    near: float = 0.1,
) -> CameraGroundTruth:
    """Project boxes given in a camera frame; keep those with a visible 2D box.

    Every projected box takes part in the occlusion test as an occluder, whatever its
    class; the result holds only the boxes whose clipped 2D box has positive area.

    Args:
        annotation_rows: (N,) ids carried through (sample_annotation rows).
        classes: (N,) detection classes.
        center_cam, size, rotation_cam: (N, 3), (N, 3) (w, l, h), (N, 4) boxes in the camera frame.
        intrinsic: (3, 3) camera matrix.
        image_size: (W, H) pixels.
        near: near-plane depth for the projection, metres.
    """
    center_cam = np.asarray(center_cam, dtype=np.float64).reshape(-1, 3)
    size = np.asarray(size, dtype=np.float64).reshape(-1, 3)
    rotation_cam = np.asarray(rotation_cam, dtype=np.float64).reshape(-1, 4)
    corners = box_corners(center_cam, size, rotation_cam)
    boxes2d, truncation, valid = project_boxes_to_image(corners, intrinsic, image_size, near=near)
    distance = np.linalg.norm(center_cam, axis=1)
    occlusion = np.ones(len(center_cam))
    occlusion[valid] = occlusion_fractions(boxes2d[valid], distance[valid])
    return CameraGroundTruth(
        annotation_rows=np.asarray(annotation_rows, dtype=np.int64)[valid],
        classes=np.asarray(classes, dtype=str)[valid],
        boxes2d=boxes2d[valid],
        truncation=truncation[valid],
        occlusion=occlusion[valid],
        distance=distance[valid],
        center_cam=center_cam[valid],
        size=size[valid],
        rotation_cam=rotation_cam[valid],
    )
