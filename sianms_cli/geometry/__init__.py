"""Numpy-only geometry: quaternions, frames, box arrays, projection, frustums, camera rig.

Frames and units follow nuScenes (metres, radians, global -> ego -> sensor, quaternions
w, x, y, z, box size w, l, h); points are row-major (N, 3) arrays.
"""

from sianms_cli.geometry.boxes import box_corners, count_points_in_boxes, points_in_boxes, points_in_own_boxes
from sianms_cli.geometry.frustum import (
    frustum_angle,
    frustum_corners,
    frustum_members,
    points_in_frustum,
    rotate_from_frustum,
    rotate_to_frustum,
)
from sianms_cli.geometry.projection import (
    BoxVisibility,
    box_in_image,
    occlusion_fractions,
    project_boxes_to_image,
    view_points,
)
from sianms_cli.geometry.quaternion import (
    matrix_to_quat,
    quat_multiply,
    quat_to_matrix,
    quat_yaw,
    yaw_to_quat,
)
from sianms_cli.geometry.camera_ring import CameraRig
from sianms_cli.geometry.transforms import (
    apply_transform,
    global_to_sensor,
    invert_transform,
    make_transform,
    sensor_to_global,
    transform_boxes,
)

__all__ = [
    "BoxVisibility",
    "CameraRig",
    "apply_transform",
    "box_corners",
    "box_in_image",
    "count_points_in_boxes",
    "frustum_angle",
    "frustum_corners",
    "frustum_members",
    "global_to_sensor",
    "invert_transform",
    "make_transform",
    "matrix_to_quat",
    "occlusion_fractions",
    "points_in_boxes",
    "points_in_frustum",
    "points_in_own_boxes",
    "project_boxes_to_image",
    "quat_multiply",
    "quat_to_matrix",
    "quat_yaw",
    "rotate_from_frustum",
    "rotate_to_frustum",
    "sensor_to_global",
    "transform_boxes",
    "view_points",
    "yaw_to_quat",
]
