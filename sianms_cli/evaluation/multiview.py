"""Multi-view frustum aggregation of siaNMS (paper §III-C, eqs. 1-2, Fig. 3).

A matched pair of detections, one in each camera of a contiguous pair, becomes one frustum
(docs/methods.md#multi-view-frustums):

1. :func:`frustums_overlap`: each detection's frustum seen from above is the wedge from its
   camera's centre through the left and right edges of its 2-D box, cut at the maximum
   detection distance; a match whose two wedges do not intersect is dismissed.
2. :func:`multi_frustum_angle`: each frustum's central ray meets the circle of the maximum
   detection distance around the reference camera's centre at p_l and p_r; the axis runs
   from that centre to their midpoint p_m. The reference camera is the pair's first
   (clockwise); the second camera's ray starts from its own centre.
3. :func:`pair_union`: the LiDAR points inside either frustum (each tested in its own camera,
   with the cache's depth window), in the reference camera's frame rotated about its y axis
   so the central axis is +z, the frame Frustum PointNets expects.

Everything is done in the reference camera's frame, whose x-z plane is the bird's-eye view
(camera y points down). Angles follow :func:`sianms_cli.geometry.frustum.frustum_angle`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sianms_cli.geometry.frustum import pixel_rays, points_in_frustum, rotate_to_frustum


def frustum_wedge(box2d: np.ndarray, intrinsic: np.ndarray, cam_to_ref: np.ndarray,
                  max_distance: float) -> np.ndarray:
    """(3, 3) corners of a 2-D box's frustum wedge, seen from above, in a target frame.

    The apex is the camera centre; the far corners lie on the rays through the box's left and
    right edges (at the box's vertical centre) at depth ``max_distance`` in the box's camera.
    In a camera frame the bird's-eye view is (x, z); in the ego or global frame, (x, y).

    Args:
        box2d: (4,) [x1, y1, x2, y2] pixels.
        intrinsic: (3, 3) of the box's camera.
        cam_to_ref: (4, 4) box's camera -> target frame transform.
        max_distance: metres.
    """
    x1, y1, x2, y2 = np.asarray(box2d, dtype=np.float64)
    middle = 0.5 * (y1 + y2)
    edges = max_distance * pixel_rays(np.array([[x1, middle], [x2, middle]]), intrinsic)
    return np.concatenate([np.zeros((1, 3)), edges]) @ cam_to_ref[:3, :3].T + cam_to_ref[:3, 3]


def frustums_overlap(wedge_a: np.ndarray, wedge_b: np.ndarray) -> np.ndarray:
    """Whether pairs of BEV triangles intersect (separating-axis theorem; touching counts).

    Args:
        wedge_a, wedge_b: (P, 3, 2) triangles (any vertex order).

    Returns:
        (P,) bool.
    """
    wedge_a = np.asarray(wedge_a, dtype=np.float64).reshape(-1, 3, 2)
    wedge_b = np.asarray(wedge_b, dtype=np.float64).reshape(-1, 3, 2)
    edges = np.concatenate([np.roll(wedge_a, -1, axis=1) - wedge_a, np.roll(wedge_b, -1, axis=1) - wedge_b], axis=1)
    axes = np.stack([-edges[..., 1], edges[..., 0]], axis=-1)  # (P, 6, 2) edge normals
    project_a = np.einsum("pkd,pvd->pkv", axes, wedge_a)
    project_b = np.einsum("pkd,pvd->pkv", axes, wedge_b)
    separated = (project_a.max(axis=2) < project_b.min(axis=2)) | (project_b.max(axis=2) < project_a.min(axis=2))
    return ~separated.any(axis=1)


def circle_exit(origin: np.ndarray, direction: np.ndarray, radius: float) -> np.ndarray:
    """(P, 2) where rays from points inside a circle centred at 0 leave it (eqs. 1-2's F ∩ C_d).

    Args:
        origin: (P, 2) ray origins, inside the circle.
        direction: (P, 2) ray directions (any length, not zero).
        radius: the circle's radius.
    """
    origin = np.asarray(origin, dtype=np.float64).reshape(-1, 2)
    direction = np.asarray(direction, dtype=np.float64).reshape(-1, 2)
    a = np.einsum("pd,pd->p", direction, direction)
    b = np.einsum("pd,pd->p", origin, direction)
    c = np.einsum("pd,pd->p", origin, origin) - radius**2
    t = (-b + np.sqrt(b * b - a * c)) / a
    return origin + t[:, None] * direction


def multi_frustum_angle(ray_a: np.ndarray, origin_b: np.ndarray, ray_b: np.ndarray, max_distance: float) -> np.ndarray:
    """Rotation angle (as ``frustum_angle``) of the multi-frustum axis, in the reference camera.

    Args:
        ray_a: (P, 2) (x, z) direction of the reference detection's central ray.
        origin_b: (P, 2) (x, z) centre of the second camera, in the reference camera's frame.
        ray_b: (P, 2) (x, z) direction of the second detection's central ray, same frame.
        max_distance: radius of the circle C_d, metres (it must enclose the second camera).

    Returns:
        (P,) radians: rotating by it puts p_m on +z.
    """
    ray_a = np.asarray(ray_a, dtype=np.float64).reshape(-1, 2)
    p_l = circle_exit(np.zeros_like(ray_a), ray_a, max_distance)
    p_r = circle_exit(origin_b, ray_b, max_distance)
    p_m = 0.5 * (p_l + p_r)
    return np.pi / 2 - np.arctan2(p_m[:, 1], p_m[:, 0])


def union_members(points_global: np.ndarray, to_cam: tuple[np.ndarray, np.ndarray], boxes2d: np.ndarray,
                  intrinsics: tuple[np.ndarray, np.ndarray], min_depth: float, max_depth: float) -> np.ndarray:
    """(P,) bool: the points inside either detection's frustum, each tested in its own camera.

    Args:
        points_global: (P, 3) LiDAR points.
        to_cam: the (4, 4) global -> camera transforms of the two detections' cameras.
        boxes2d: (2, 4) the two 2-D boxes.
        intrinsics: the two (3, 3) camera matrices.
        min_depth, max_depth: the cache's frustum depth window.
    """
    inside = np.zeros(len(points_global), dtype=bool)
    for transform, box, intrinsic in zip(to_cam, boxes2d, intrinsics):
        points_cam = points_global @ transform[:3, :3].T + transform[:3, 3]
        inside |= points_in_frustum(points_cam, box, intrinsic, min_depth, max_depth)
    return inside


def union_frustum(points_global: np.ndarray, to_ref: np.ndarray, angle: float) -> np.ndarray:
    """(M, 3) the union's points in the multi-frustum frame (reference camera rotated by ``angle``)."""
    points_ref = points_global @ to_ref[:3, :3].T + to_ref[:3, 3]
    return rotate_to_frustum(points_ref, angle)


@dataclass(frozen=True, eq=False)
class PairGeometry:
    """The aggregation geometry of P matched pairs (detection a in the reference camera).

    Attributes:
        overlap: (P,) bool, the two frustum wedges intersect (else the match is dismissed).
        angle: (P,) the multi-frustum angle in the reference camera (:func:`multi_frustum_angle`).
        wedges: (P, 2, 3, 3) both wedges' corners in the global frame (a's, then b's).
        to_ref: (P, 4, 4) global -> reference camera; to_b: (P, 4, 4) global -> b's camera.
    """

    overlap: np.ndarray
    angle: np.ndarray
    wedges: np.ndarray
    to_ref: np.ndarray
    to_b: np.ndarray


def _moved(corners: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """(P, K, 3) corners moved by one (4, 4) transform each."""
    return np.einsum("pij,pkj->pki", transforms[:, :3, :3], corners) + transforms[:, None, :3, 3]


def pair_geometry(boxes_a: np.ndarray, boxes_b: np.ndarray, cam_to_global_a: np.ndarray, cam_to_global_b: np.ndarray,
                  intrinsic_a: np.ndarray, intrinsic_b: np.ndarray, max_distance: float) -> PairGeometry:
    """Overlap test, multi-frustum axis and wedges of P pairs (module docstring, steps 1-2).

    Args:
        boxes_a, boxes_b: (P, 4) 2-D boxes of the two detections.
        cam_to_global_a, cam_to_global_b: (P, 4, 4) their cameras' poses.
        intrinsic_a, intrinsic_b: (P, 3, 3).
        max_distance: metres.
    """
    count = len(boxes_a)
    to_ref = np.linalg.inv(cam_to_global_a)
    b_in_ref = to_ref @ cam_to_global_b
    wedges = np.stack([
        np.stack([frustum_wedge(box, k, pose, max_distance) for box, k, pose in zip(boxes, ks, poses)])
        if count else np.zeros((0, 3, 3))
        for boxes, ks, poses in ((boxes_a, intrinsic_a, cam_to_global_a), (boxes_b, intrinsic_b, cam_to_global_b))
    ], axis=1)
    overlap = frustums_overlap(_moved(wedges[:, 0], to_ref)[..., [0, 2]], _moved(wedges[:, 1], to_ref)[..., [0, 2]])
    ray_a = (np.stack([pixel_rays(_centre(box), k)[0] for box, k in zip(boxes_a, intrinsic_a)])
             if count else np.zeros((0, 3)))
    ray_b = (np.stack([m[:3, :3] @ pixel_rays(_centre(box), k)[0] for box, k, m in zip(boxes_b, intrinsic_b, b_in_ref)])
             if count else np.zeros((0, 3)))
    angle = multi_frustum_angle(ray_a[:, [0, 2]], b_in_ref[:, [0, 2], 3], ray_b[:, [0, 2]], max_distance)
    return PairGeometry(overlap=overlap, angle=angle, wedges=wedges, to_ref=to_ref, to_b=np.linalg.inv(cam_to_global_b))


def _centre(box2d: np.ndarray) -> np.ndarray:
    return np.array([[0.5 * (box2d[0] + box2d[2]), 0.5 * (box2d[1] + box2d[3])]])


def pair_union(points_global: np.ndarray, geometry: PairGeometry, k: int | np.integer, boxes2d: np.ndarray,
               intrinsics: tuple[np.ndarray, np.ndarray], min_depth: float, max_depth: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Pair ``k``'s union frustum: (P,) bool members of ``points_global`` and their (M, 3) points
    in the multi-frustum frame (module docstring, step 3)."""
    inside = union_members(points_global, (geometry.to_ref[k], geometry.to_b[k]), boxes2d, intrinsics,
                           min_depth, max_depth)
    return inside, union_frustum(points_global[inside], geometry.to_ref[k], geometry.angle[k])
