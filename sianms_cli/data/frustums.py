"""LiDAR frustums of 2D detections, as Frustum PointNets prepares them (docs/methods.md#frustums).

Points are in the camera frame (x right, y down, z forward, metres), then rotated about the
camera y axis by ``rot_angle`` (:func:`sianms_cli.geometry.frustum.frustum_angle`) so the ray
through the 2D box centre becomes +z. Each point's label is 1 when it lies inside the
associated ground-truth box, else 0; the box's centre and heading are given in both frames.

:func:`extract_frustums` does all the detections of one camera at once (the points are
projected once, not once per box).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from sianms_cli.geometry.boxes import points_in_own_boxes
from sianms_cli.geometry.frustum import frustum_angle, frustum_members, rotate_to_frustum
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


@dataclass(frozen=True, eq=False)
class Frustums:
    """The frustums of N detections of one camera, their points concatenated in detection order.

    Attributes:
        rot_angle: (N,) camera -> frustum frame angle of each detection (radians).
        offsets: (N + 1,) int64: the points of detection n are rows ``offsets[n]:offsets[n + 1]``.
        points: (M, 3) float64 frustum-frame points (each in its own detection's frame).
        extra: (M, k) per-point channels carried through (intensity, time lag).
        labels: (M,) int8, 1 inside the detection's associated box.
        has_box: (N,) bool, the detection has an associated box; the box arrays below are
            NaN where it has none.
        box_center_cam, box_size, box_rotation_cam: (N, 3), (N, 3) (w, l, h), (N, 4).
        box_heading_cam: (N,) F-PointNets heading of the box in the camera frame.
        box_center_frustum: (N, 3) box centre in the detection's frustum frame.
        box_heading_frustum: (N,) heading in the frustum frame (``heading_cam - rot_angle``).
    """

    rot_angle: np.ndarray
    offsets: np.ndarray
    points: np.ndarray
    extra: np.ndarray
    labels: np.ndarray
    has_box: np.ndarray
    box_center_cam: np.ndarray
    box_size: np.ndarray
    box_rotation_cam: np.ndarray
    box_heading_cam: np.ndarray
    box_center_frustum: np.ndarray
    box_heading_frustum: np.ndarray

    def __len__(self) -> int:
        return len(self.rot_angle)

    @property
    def counts(self) -> np.ndarray:
        """(N,) int64 points per frustum."""
        return np.diff(self.offsets)

    @staticmethod
    def concatenate(parts: list[Frustums]) -> Frustums:
        """The frustums of several cameras one after the other (at least one part)."""
        counts = np.concatenate([part.counts for part in parts])
        offsets = np.zeros(len(counts) + 1, dtype=np.int64)
        np.cumsum(counts, out=offsets[1:])
        joined = {field.name: np.concatenate([getattr(part, field.name) for part in parts])
                  for field in fields(Frustums) if field.name != "offsets"}
        return Frustums(offsets=offsets, **joined)


def heading_in_camera(rotation_cam: np.ndarray) -> np.ndarray:
    """F-PointNets heading ``ry = atan2(-v_z, v_x)`` of each box's length axis v (camera frame).

    Args:
        rotation_cam: (N, 4) quaternions (w, x, y, z) in the camera frame.
    """
    forward = quat_to_matrix(np.asarray(rotation_cam, dtype=np.float64).reshape(-1, 4))[:, :, 0]
    return np.arctan2(-forward[:, 2], forward[:, 0])


def extract_frustums(
    points_cam: np.ndarray,
    extra: np.ndarray,
    boxes2d: np.ndarray,
    intrinsic: np.ndarray,
    box_center_cam: np.ndarray,
    box_size: np.ndarray,
    box_rotation_cam: np.ndarray,
    has_box: np.ndarray,
    min_depth: float = 1.0,
    max_depth: float = np.inf,
) -> Frustums:
    """The frustums of all 2D boxes of one camera, equal row for row to cutting each box's frustum on its own (tested).

    Membership comes from :func:`~sianms_cli.geometry.frustum.frustum_members` (points
    projected once, a memory-bounded boxes x points mask); each point is rotated by its own
    detection's angle, and labelled by :func:`~sianms_cli.geometry.boxes.points_in_boxes`
    against its own detection's box (:func:`~sianms_cli.geometry.boxes.points_in_own_boxes`).

    Args:
        points_cam: (P, 3) LiDAR points in the camera frame.
        extra: (P, k) channels kept with each point.
        boxes2d: (N, 4) [x1, y1, x2, y2] pixels (bounds inclusive).
        intrinsic: (3, 3) camera matrix.
        box_center_cam, box_size, box_rotation_cam: (N, 3), (N, 3), (N, 4) the associated
            boxes; rows where ``has_box`` is false are ignored.
        has_box: (N,) bool.
        min_depth, max_depth: depth window (exclusive), metres; 1 m as the devkit's
            ``map_pointcloud_to_image``.
    """
    points_cam = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    extra = np.asarray(extra)
    boxes2d = np.asarray(boxes2d, dtype=np.float64).reshape(-1, 4)
    count = len(boxes2d)
    has_box = np.asarray(has_box, dtype=bool).reshape(count)
    owner, chosen = frustum_members(points_cam, boxes2d, intrinsic, min_depth, max_depth)
    angle = frustum_angle(boxes2d, intrinsic)
    offsets = np.searchsorted(owner, np.arange(count + 1))
    center = np.where(has_box[:, None], np.asarray(box_center_cam, dtype=np.float64).reshape(-1, 3), np.nan)
    size = np.where(has_box[:, None], np.asarray(box_size, dtype=np.float64).reshape(-1, 3), np.nan)
    rotation = np.where(has_box[:, None], np.asarray(box_rotation_cam, dtype=np.float64).reshape(-1, 4), np.nan)
    boxed = np.flatnonzero(has_box)
    heading = np.full(count, np.nan)
    heading[boxed] = heading_in_camera(rotation[boxed])
    return Frustums(
        rot_angle=angle,
        offsets=offsets,
        points=rotate_to_frustum(points_cam[chosen], angle[owner]),
        extra=extra[chosen],
        labels=_labels(points_cam[chosen], owner, center, size, rotation, has_box),
        has_box=has_box,
        box_center_cam=center,
        box_size=size,
        box_rotation_cam=rotation,
        box_heading_cam=heading,
        box_center_frustum=rotate_to_frustum(center, angle),
        box_heading_frustum=heading - angle,
    )


def _labels(points: np.ndarray, owner: np.ndarray, center: np.ndarray, size: np.ndarray, rotation: np.ndarray,
            has_box: np.ndarray) -> np.ndarray:
    """(M,) int8: 1 where a point lies in its own detection's box (``owner``), bit for bit the
    one-box :func:`~sianms_cli.geometry.boxes.points_in_boxes` test."""
    boxed = np.flatnonzero(has_box)
    compact = np.cumsum(has_box) - 1  # index of a detection's box among the boxed ones
    mine = has_box[owner]
    labels = np.zeros(len(points), dtype=np.int8)
    labels[mine] = points_in_own_boxes(points[mine], compact[owner[mine]], center[boxed], size[boxed], rotation[boxed])
    return labels
