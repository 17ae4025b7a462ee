"""The camera rig of each sample, built from the calibrated_sensor records of its key frames.

A sample's rig is the :class:`~sianms_cli.geometry.camera_ring.CameraRig` of the cameras that have a
key frame in that sample (the devkit's ``sample['data']``, where a later key frame of the same
channel wins), with their calibrated_sensor extrinsics and intrinsics and the image size of the
key-frame sample_data. Real logs calibrate once per scene, so a dataset holds few distinct
rigs; each is built once.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from sianms_cli.errors import DataFormatError
from sianms_cli.geometry.camera_ring import CameraRig
from sianms_cli.nuscenes.loader import NuScenesDB


def sample_rigs(db: NuScenesDB, sample_tokens: Sequence[str] | np.ndarray) -> tuple[list[CameraRig], np.ndarray]:
    """The distinct rigs of some samples and which one each sample has.

    Args:
        db: the loaded dataset.
        sample_tokens: S sample tokens (DataFormatError for an unknown one).

    Returns:
        ``(rigs, index)``: the distinct rigs, and (S,) int64 the rig of each sample, -1 for a
        sample without any camera key frame.
    """
    sample_rows = db.table("sample").indices(list(sample_tokens))
    sample_data = db.table("sample_data")
    cameras = np.flatnonzero(sample_data.column("is_key_frame") & (db.sample_data_modalities() == "camera"))
    owners = sample_data.rows("sample_token")[cameras]
    channels = db.sample_data_channels()[cameras]
    # Sort by (sample, channel, file row); the last row of a (sample, channel) run wins.
    order = np.lexsort((cameras, channels, owners))
    cameras, owners, channels = cameras[order], owners[order], channels[order]
    last = np.r_[(owners[1:] != owners[:-1]) | (channels[1:] != channels[:-1]), True][:len(owners)]  # none: none
    cameras, owners, channels = cameras[last], owners[last], channels[last]
    calibrations = sample_data.rows("calibrated_sensor_token")[cameras]
    widths = sample_data.column("width")[cameras]
    heights = sample_data.column("height")[cameras]
    for field, sizes in (("width", widths), ("height", heights)):
        if (sizes <= 0).any():
            row = cameras[np.flatnonzero(sizes <= 0)[0]]
            raise DataFormatError(sample_data.path, f"a camera key frame needs a positive image {field}, "
                                  f"got {sizes[sizes <= 0][0]}", token=str(sample_data.tokens[row]), field=field)
    calibrated = db.table("calibrated_sensor")
    without = np.isnan(calibrated.column("camera_intrinsic")[calibrations]).any(axis=(1, 2))
    if without.any():
        row = calibrations[np.flatnonzero(without)[0]]
        raise DataFormatError(calibrated.path, "a camera's calibration needs its intrinsic matrix, got []",
                              token=str(calibrated.tokens[row]), field="camera_intrinsic")

    first = np.searchsorted(owners, sample_rows, side="left")
    stop = np.searchsorted(owners, sample_rows, side="right")
    rigs: list[CameraRig] = []
    known: dict[tuple, int] = {}
    index = np.full(len(sample_rows), -1, dtype=np.int64)
    for i, (lo, hi) in enumerate(zip(first.tolist(), stop.tolist())):
        if lo == hi:
            continue
        key = tuple(zip(channels[lo:hi].tolist(), calibrations[lo:hi].tolist(),
                        widths[lo:hi].tolist(), heights[lo:hi].tolist()))
        if key not in known:
            known[key] = len(rigs)
            rigs.append(_rig(db, key))
        index[i] = known[key]
    return rigs, index


def _rig(db: NuScenesDB, cameras: tuple[tuple[str, int, int, int], ...]) -> CameraRig:
    """The rig of (channel, calibrated_sensor row, width, height) per camera."""
    calibrated = db.table("calibrated_sensor")
    channels = [camera[0] for camera in cameras]
    rows = np.array([camera[1] for camera in cameras], dtype=np.int64)
    sizes = np.array([camera[2:] for camera in cameras], dtype=np.int64)
    return CameraRig.from_calibration(channels, calibrated.column("rotation")[rows],
                                      calibrated.column("translation")[rows],
                                      calibrated.column("camera_intrinsic")[rows], sizes)
