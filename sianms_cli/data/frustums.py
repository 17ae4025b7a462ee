"""LiDAR frustums of 2D detections, as Frustum PointNets prepares them (models.md §1.1-1.2).

Points are in the camera frame (x right, y down, z forward, metres), then rotated about the
camera y axis by ``rot_angle`` (:func:`sianms_cli.geometry.frustum.frustum_angle`) so the ray
through the 2D box centre becomes +z. Each point's label is 1 when it lies inside the
associated ground-truth box, else 0; the box's centre and heading are given in both frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sianms_cli.geometry.boxes import points_in_boxes
from sianms_cli.geometry.frustum import frustum_angle, points_in_frustum, rotate_to_frustum
from sianms_cli.geometry.quaternion import quat_to_matrix


@dataclass(frozen=True)
class Frustum:
    """One detection's frustum.

    Attributes:
        rot_angle: camera -> frustum frame angle (radians).
        points: (M, 3) float64 frustum-frame points.
        extra: (M, k) per-point channels carried through (intensity, time lag).
        labels: (M,) int8, 1 inside the associated box.
        box: None, or dict with center_cam (3,), size (3,) (w, l, h), rotation_cam (4,),
            heading_cam, center_frustum (3,), heading_frustum.
    """

    rot_angle: float
    points: np.ndarray
    extra: np.ndarray
    labels: np.ndarray
    box: dict | None


def heading_in_camera(rotation_cam: np.ndarray) -> np.ndarray:
    """F-PointNets heading ``ry = atan2(-v_z, v_x)`` of each box's length axis v (camera frame).

    Args:
        rotation_cam: (N, 4) quaternions (w, x, y, z) in the camera frame.
    """
    forward = quat_to_matrix(np.asarray(rotation_cam, dtype=np.float64).reshape(-1, 4))[:, :, 0]
    return np.arctan2(-forward[:, 2], forward[:, 0])


def extract_frustum(
    points_cam: np.ndarray,
    extra: np.ndarray,
    box2d: np.ndarray,
    intrinsic: np.ndarray,
    gt_center_cam: np.ndarray | None = None,
    gt_size: np.ndarray | None = None,
    gt_rotation_cam: np.ndarray | None = None,
    min_depth: float = 1.0,
    max_depth: float = np.inf,
) -> Frustum:
    """The frustum of one 2D box.

    Args:
        points_cam: (P, 3) LiDAR points in the camera frame.
        extra: (P, k) channels kept with each point.
        box2d: (4,) [x1, y1, x2, y2] pixels (bounds inclusive).
        intrinsic: (3, 3) camera matrix.
        gt_center_cam, gt_size, gt_rotation_cam: the associated box (3,), (3,), (4,), or None.
        min_depth, max_depth: depth window (exclusive), metres; 1 m as the devkit's
            ``map_pointcloud_to_image``.
    """
    inside = points_in_frustum(points_cam, box2d, intrinsic, min_depth=min_depth, max_depth=max_depth)
    angle = float(frustum_angle(np.asarray(box2d).reshape(1, 4), intrinsic)[0])
    chosen = np.asarray(points_cam, dtype=np.float64)[inside]
    rotated = rotate_to_frustum(chosen, angle)
    labels = np.zeros(len(chosen), dtype=np.int8)
    box = None
    if gt_center_cam is not None:
        center = np.asarray(gt_center_cam, dtype=np.float64).reshape(1, 3)
        size = np.asarray(gt_size, dtype=np.float64).reshape(1, 3)
        rotation = np.asarray(gt_rotation_cam, dtype=np.float64).reshape(1, 4)
        if len(chosen):
            labels = points_in_boxes(chosen, center, size, rotation)[0].astype(np.int8)
        heading = float(heading_in_camera(rotation)[0])
        box = {
            "center_cam": center[0],
            "size": size[0],
            "rotation_cam": rotation[0],
            "heading_cam": heading,
            "center_frustum": rotate_to_frustum(center, angle)[0],
            "heading_frustum": heading - angle,
        }
    return Frustum(angle, rotated, np.asarray(extra)[inside], labels, box)
