"""Sample records as arrays: each sample's key frame per channel, their poses and calibrations,
and the LiDAR sweep chains before them.

The vectorised counterpart of the loader's record-by-record ``keyframe_data``, ``ego_pose_of``
and ``calibration_of``: one call serves a whole scene or split, so per-sample work looks
nothing up by token (as :mod:`sianms_cli.metrics.dataset` does for the evaluation).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from sianms_cli.errors import DataFormatError
from sianms_cli.nuscenes.loader import NuScenesDB


def keyframe_rows(db: NuScenesDB, sample_rows: np.ndarray, channels: Sequence[str]) -> np.ndarray:
    """The key-frame sample_data of each sample and channel (the devkit's ``sample['data']``).

    Args:
        db: the loaded dataset.
        sample_rows: (S,) rows in the sample table, distinct.
        channels: C channel names (``CAM_FRONT``, ``LIDAR_TOP``, ...).

    Returns:
        (S, C) int64 sample_data rows, -1 where the sample has no key frame of the channel.
        As in the devkit, a later key frame (in file order) of the same channel wins.
    """
    sample_rows = np.asarray(sample_rows, dtype=np.int64).reshape(-1)
    sample_data = db.table("sample_data")
    keyframes = np.flatnonzero(sample_data.column("is_key_frame"))
    position = np.full(len(db.table("sample")), -1, dtype=np.int64)
    position[sample_rows] = np.arange(len(sample_rows))
    owner = position[sample_data.rows("sample_token")[keyframes]]
    keyframe_channels = db.sample_data_channels()[keyframes]
    column = np.full(len(keyframes), -1, dtype=np.int64)
    for c, name in enumerate(channels):
        column[keyframe_channels == name] = c
    known = (owner >= 0) & (column >= 0)
    rows = np.full((len(sample_rows), len(channels)), -1, dtype=np.int64)
    np.maximum.at(rows, (owner[known], column[known]), keyframes[known])
    return rows


@dataclass(frozen=True, eq=False)
class SensorRecords:
    """The sample_data records of some rows, aligned with them (any shape R).

    Rows < 0 stand for "no record": token "", timestamp and previous -1, NaN poses.

    Attributes:
        rows: R int64 sample_data rows.
        tokens: R str sample_data tokens.
        timestamps: R int64 microseconds.
        previous: R int64 row of the previous record of the same sensor (``prev``), -1 for none.
        ego_rotation, ego_translation: R x (4,), R x (3,) ego pose (ego -> global).
        sensor_rotation, sensor_translation: R x (4,), R x (3,) calibration (sensor -> ego).
        intrinsic: R x (3, 3) camera matrix, NaN for a LiDAR or radar.
    """

    rows: np.ndarray
    tokens: np.ndarray
    timestamps: np.ndarray
    previous: np.ndarray
    ego_rotation: np.ndarray
    ego_translation: np.ndarray
    sensor_rotation: np.ndarray
    sensor_translation: np.ndarray
    intrinsic: np.ndarray


def sensor_records(db: NuScenesDB, rows: np.ndarray) -> SensorRecords:
    """The records of ``rows`` (any shape; -1 for none) with their ego poses and calibrations."""
    rows = np.asarray(rows, dtype=np.int64)
    found = rows >= 0
    safe = np.where(found, rows, 0)
    sample_data = db.table("sample_data")
    poses = sample_data.rows("ego_pose_token")[safe]
    calibrations = sample_data.rows("calibrated_sensor_token")[safe]
    ego, calibrated = db.table("ego_pose"), db.table("calibrated_sensor")

    def pick(values: np.ndarray, fill) -> np.ndarray:
        return np.where(found.reshape(found.shape + (1,) * (values.ndim - found.ndim)), values, fill)

    return SensorRecords(
        rows=np.where(found, rows, -1),
        tokens=pick(sample_data.tokens[safe], ""),
        timestamps=pick(sample_data.column("timestamp")[safe], -1),
        previous=pick(sample_data.rows("prev")[safe], -1),
        ego_rotation=pick(ego.column("rotation")[poses], np.nan),
        ego_translation=pick(ego.column("translation")[poses], np.nan),
        sensor_rotation=pick(calibrated.column("rotation")[calibrations], np.nan),
        sensor_translation=pick(calibrated.column("translation")[calibrations], np.nan),
        intrinsic=pick(calibrated.column("camera_intrinsic")[calibrations], np.nan),
    )


def sweep_rows(db: NuScenesDB, rows: np.ndarray, sweeps: int) -> np.ndarray:
    """Each row followed by up to ``sweeps`` earlier records of its sensor (the ``prev`` chain).

    Args:
        db: the loaded dataset.
        rows: (N,) sample_data rows (key frames), -1 for none.
        sweeps: how many earlier records to add.

    Returns:
        (N, sweeps + 1) int64: column 0 is ``rows``, column k the k-th earlier record, -1
        once the chain has ended.

    Raises:
        DataFormatError naming the record and its ``prev`` when the link goes to another sensor's
        record or to one not strictly earlier (a loop or a step forwards): stacked, it would
        read one sweep several times with a lag of 0, or with a negative one.
    """
    sample_data = db.table("sample_data")
    previous = sample_data.rows("prev")
    channels, times = db.sample_data_channels(), sample_data.column("timestamp")
    chain = np.full((len(rows), sweeps + 1), -1, dtype=np.int64)
    chain[:, 0] = rows
    for k in range(sweeps):
        current = chain[:, k]
        earlier = np.where(current >= 0, previous[np.maximum(current, 0)], -1)
        here, there = np.maximum(current, 0), np.maximum(earlier, 0)
        broken = np.flatnonzero((earlier >= 0) & ((channels[there] != channels[here]) | (times[there] >= times[here])))
        if len(broken):
            row, link = here[broken[0]], there[broken[0]]
            problem = (f"a {channels[link]} record, not {channels[row]}'s" if channels[link] != channels[row]
                       else f"not earlier (timestamp {times[link]}, this record's {times[row]})")
            raise DataFormatError(sample_data.path, f"prev {sample_data.tokens[link]} is {problem}",
                                  token=str(sample_data.tokens[row]), field="prev")
        chain[:, k + 1] = earlier
    return chain
