"""The annotated 3D boxes one camera sees, as the 2D ground truth of its image.

Everything is computed from geometry alone (the annotated boxes and the camera
calibration), so it runs unchanged on real nuScenes. Camera frame: x right, y down,
z forward, metres; pixels as in :mod:`sianms_cli.geometry.projection`. It lives with
`sianms prepare` because it is the one place where 3D boxes become 2D ground truth:
``detection2d/`` downstream knows only the 2D result.
"""

from __future__ import annotations

import numpy as np

from sianms_cli.detection2d.detections import GroundTruth2D
from sianms_cli.geometry.boxes import box_corners
from sianms_cli.geometry.projection import occlusion_fractions, project_boxes_to_image


def camera_ground_truth(
    classes: np.ndarray,
    center_cam: np.ndarray,
    size: np.ndarray,
    rotation_cam: np.ndarray,
    intrinsic: np.ndarray,
    image_size: tuple[int, int],
    near: float = 0.1,
) -> GroundTruth2D:
    """Project boxes given in a camera frame; keep those with a visible 2D box.

    Every projected box takes part in the occlusion test as an occluder, whatever its
    class; the result holds only the boxes whose clipped 2D box has positive area, with
    ``ids`` their rows in the inputs.

    Args:
        classes: (N,) detection classes ("" for ignored categories).
        center_cam, size, rotation_cam: (N, 3), (N, 3) (w, l, h), (N, 4) boxes in the camera frame.
        intrinsic: (3, 3) camera matrix.
        image_size: (W, H) pixels.
        near: near-plane depth for the projection, metres.
    """
    center_cam = np.asarray(center_cam, dtype=np.float64).reshape(-1, 3)
    corners = box_corners(center_cam, size, rotation_cam)
    boxes2d, truncation, valid = project_boxes_to_image(corners, intrinsic, image_size, near=near)
    distance = np.linalg.norm(center_cam, axis=1)
    occlusion = np.ones(len(center_cam))
    occlusion[valid] = occlusion_fractions(boxes2d[valid], distance[valid])
    return GroundTruth2D(
        ids=np.flatnonzero(valid),
        boxes=boxes2d[valid],
        classes=np.asarray(classes, dtype=str)[valid],
        truncation=truncation[valid],
        occlusion=occlusion[valid],
        distance=distance[valid],
    )
