"""Which keyframe cameras give each 3-D annotation an image box, by the devkit's 2-D export rule.

nuScenes publishes how many 2-D boxes its 3-D boxes give (nuscenes-devkit issue #457, from
``export_2d_annotations_as_json.py``), and the excess over one per box is how often one object
is imaged twice: the duplicates siaNMS removes. To hold a dataroot against that figure we
apply the same rule, per annotation and keyframe camera of its sample:

- the box goes global -> ego -> camera with the camera key frame's own ego pose and calibration;
- the corners with depth z > 0 are kept and projected;
- their convex hull is intersected with the image canvas; the camera images the box when the
  intersection has positive area (:func:`sianms_cli.geometry.clip.hull_meets_rectangle`).

The canvas is each key frame's width x height (the devkit fixes 1600 x 900, the size of every
real nuScenes image). Work runs over chunks of annotations x all cameras, never per box.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sianms_cli.geometry.boxes import box_corners
from sianms_cli.geometry.clip import hull_meets_rectangle
from sianms_cli.geometry.quaternion import quat_to_matrix
from sianms_cli.nuscenes.keyframes import keyframe_rows, sensor_records
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.progress import SILENT, Progress

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
CHUNK = 16_384  # annotations per chunk: the (chunk, cameras, 8, 3) corner array stays ~20 MB


@dataclass(frozen=True, eq=False)
class ImageBoxes:
    """Which cameras image each annotation.

    Attributes:
        channels: the C camera channels, sorted.
        imaged: (A, C) bool, annotation rows x channels.
    """

    channels: tuple[str, ...]
    imaged: np.ndarray


def annotation_image_boxes(db: NuScenesDB, progress: Progress = SILENT, chunk: int = CHUNK) -> ImageBoxes:
    """The devkit's 2-D export rule for every annotation and every camera key frame of its sample."""
    sample_data = db.table("sample_data")
    is_camera = sample_data.column("is_key_frame") & (db.sample_data_modalities() == "camera")
    channels = tuple(sorted(set(db.sample_data_channels()[is_camera].tolist())))
    rows = keyframe_rows(db, np.arange(len(db.table("sample"))), channels)
    rotation, translation, intrinsic = _global_to_camera(db, rows)
    found = rows >= 0
    safe = np.where(found, rows, 0)
    image_size = np.where(found[..., None], np.stack([sample_data.column("width")[safe],
                                                      sample_data.column("height")[safe]], axis=-1), 0)

    annotations = db.table("sample_annotation")
    box_sample = annotations.rows("sample_token")
    centers, sizes, rotations = (annotations.column(f) for f in ("translation", "size", "rotation"))
    imaged = np.zeros((len(annotations), len(channels)), dtype=bool)
    starts = range(0, len(annotations), chunk)
    progress.start(len(starts), "chunk", "projecting boxes")
    for start in starts:
        part = slice(start, start + chunk)
        s = box_sample[part]
        imaged[part] = boxes_imaged(box_corners(centers[part], sizes[part], rotations[part]),
                                    rotation[s], translation[s], intrinsic[s], image_size[s])
        progress.advance()
    return ImageBoxes(channels, imaged)


def boxes_imaged(corners: np.ndarray, rotation: np.ndarray, translation: np.ndarray,
                 intrinsic: np.ndarray, image_size: np.ndarray) -> np.ndarray:
    """Whether each camera images each box (the devkit's 2-D export rule).

    Args:
        corners: (N, 8, 3) global box corners.
        rotation, translation: (N, C, 3, 3), (N, C, 3) global -> camera of each box's cameras
            (``p_cam = R p + t``); NaN for a missing camera.
        intrinsic: (N, C, 3, 3) camera matrices.
        image_size: (N, C, 2) width, height in pixels.

    Returns:
        (N, C) bool.
    """
    depth = _affine(rotation[:, :, 2], translation[:, :, 2], corners)
    in_front = depth > 0
    projected = _affine(intrinsic @ rotation, np.einsum("ncij,ncj->nci", intrinsic, translation), corners)
    uv = projected[..., :2] / np.where(in_front, projected[..., 2], 1.0)[..., None]
    width, height = image_size[..., 0], image_size[..., 1]
    # Cheap rejection before the hull: too few corners in front, or their extent misses the canvas.
    low = np.where(in_front[..., None], uv, np.inf).min(axis=2)
    high = np.where(in_front[..., None], uv, -np.inf).max(axis=2)
    candidate = ((in_front.sum(axis=2) >= 3) & (high[..., 0] > 0) & (high[..., 1] > 0)
                 & (low[..., 0] < width) & (low[..., 1] < height))
    rows = np.flatnonzero(candidate)
    imaged = np.zeros(candidate.size, dtype=bool)
    imaged[rows] = hull_meets_rectangle(uv.reshape(-1, 8, 2)[rows], in_front.reshape(-1, 8)[rows],
                                        width.reshape(-1)[rows], height.reshape(-1)[rows])
    return imaged.reshape(candidate.shape)


def _affine(matrix: np.ndarray, offset: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """``matrix @ corner + offset`` of every camera and corner, coordinate by coordinate
    (several times faster than a batched einsum or matmul of 3 x 3 blocks).

    Args:
        matrix: (N, C, 3) one row or (N, C, R, 3) R rows per box and camera.
        offset: (N, C) or (N, C, R).
        corners: (N, 8, 3).

    Returns:
        (N, C, 8) or (N, C, 8, R).
    """
    if matrix.ndim == 3:
        return _affine(matrix[:, :, None], offset[:, :, None], corners)[..., 0]
    x, y, z = (corners[:, None, :, None, i] for i in range(3))  # (N, 1, 8, 1)
    return (matrix[:, :, None, :, 0] * x + matrix[:, :, None, :, 1] * y + matrix[:, :, None, :, 2] * z
            + offset[:, :, None, :])


def _global_to_camera(db: NuScenesDB, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(S, C, 3, 3) rotation, (S, C, 3) translation global -> camera, (S, C, 3, 3) intrinsics.

    The devkit's chain: ``p_ego = R_e^T (p - t_e)``, ``p_cam = R_s^T (p_ego - t_s)``, with the
    camera key frame's ego pose (R_e, t_e) and calibration (R_s, t_s). NaN where ``rows`` < 0.
    """
    records = sensor_records(db, rows)
    found = (rows >= 0)[..., None]
    ego = quat_to_matrix(np.where(found, records.ego_rotation, IDENTITY))
    sensor = quat_to_matrix(np.where(found, records.sensor_rotation, IDENTITY))
    rotation = np.swapaxes(sensor, -1, -2) @ np.swapaxes(ego, -1, -2)
    translation = -(np.einsum("...ij,...j->...i", rotation, records.ego_translation)
                    + np.einsum("...ji,...j->...i", sensor, records.sensor_translation))
    return np.where(found[..., None], rotation, np.nan), translation, records.intrinsic
