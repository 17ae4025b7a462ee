"""The nuScenes sensor rig: six cameras and the top LiDAR with their real calibrations.

Values are calibrated_sensor records of two public nuScenes logs, as published in public code
(docs/synthetic_world.md#rig): set A from an n015 vehicle (Singapore), set B from
an n008 vehicle (Boston). Images are 1600 x 900; a scaled image keeps the optical
geometry by scaling the intrinsic matrix. Camera trigger offsets relative to the LiDAR
keyframe time come from a real n008 keyframe: the spinning LiDAR fires
each camera as its beam crosses the camera's field of view.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from sianms_cli.geometry.quaternion import quat_multiply, quat_to_matrix


FULL_IMAGE_SIZE = (1600, 900)

LIDAR_CHANNEL = "LIDAR_TOP"

# Camera timestamp minus LiDAR keyframe timestamp, microseconds.
CAMERA_TRIGGER_OFFSET_US = {
    "CAM_FRONT_LEFT": -42_800,
    "CAM_FRONT": -35_200,
    "CAM_FRONT_RIGHT": -27_100,
    "CAM_BACK_RIGHT": -19_500,
    "CAM_BACK": -10_000,
    "CAM_BACK_LEFT": -200,
}


def as_translation(values: np.ndarray) -> tuple[float, float, float]:
    """A (3,) translation as the floats a calibrated_sensor record holds."""
    x, y, z = (float(v) for v in values)
    return x, y, z


def as_rotation(values: np.ndarray) -> tuple[float, float, float, float]:
    """A (4,) quaternion (w, x, y, z) as the floats a calibrated_sensor record holds."""
    w, x, y, z = (float(v) for v in values)
    return w, x, y, z


@dataclass(frozen=True)
class SensorCalibration:
    """One calibrated_sensor record: sensor -> ego pose and, for cameras, intrinsics."""

    channel: str
    translation: tuple[float, float, float]
    rotation: tuple[float, float, float, float]  # w, x, y, z
    focal: float | None = None
    principal: tuple[float, float] | None = None

    def intrinsic(self, image_scale: float) -> np.ndarray:
        """(3,3) camera matrix for images scaled by ``image_scale`` from 1600 x 900."""
        assert self.focal is not None and self.principal is not None, f"{self.channel} is not a camera"
        return np.array(
            [
                [self.focal * image_scale, 0.0, self.principal[0] * image_scale],
                [0.0, self.focal * image_scale, self.principal[1] * image_scale],
                [0.0, 0.0, 1.0],
            ]
        )


RIG_SINGAPORE = (
    SensorCalibration("CAM_FRONT", (1.70079, 0.01595, 1.51096),
                      (0.4998015430569128, -0.5030316162024876, 0.4997798114386805, -0.49737083824542755),
                      1266.417203046554, (816.2670197447984, 491.50706579294757)),
    SensorCalibration("CAM_FRONT_RIGHT", (1.55085, -0.49340, 1.49575),
                      (0.20603, -0.20269, 0.68245, -0.67136), 1260.847, (807.968, 495.334)),
    SensorCalibration("CAM_BACK_RIGHT", (1.01488, -0.48057, 1.56240),
                      (0.12281, -0.13240, -0.70043, 0.69050), 1259.514, (807.253, 501.196)),
    SensorCalibration("CAM_BACK", (0.02833, 0.00345, 1.57910),
                      (0.50379, -0.49740, -0.49419, 0.50455), 809.221, (829.220, 481.778)),
    SensorCalibration("CAM_BACK_LEFT", (1.03569, 0.48480, 1.59097),
                      (0.69242, -0.70316, -0.11648, 0.11203), 1256.741, (792.113, 492.776)),
    SensorCalibration("CAM_FRONT_LEFT", (1.52388, 0.49463, 1.50933),
                      (0.67573, -0.67363, 0.21214, -0.21123), 1272.598, (826.615, 479.752)),
    SensorCalibration("LIDAR_TOP", (0.943713, 0.0, 1.84023),
                      (0.7077955119163518, -0.006492242056004365, 0.010646214713995808, -0.7063073142877817)),
)

RIG_BOSTON = (
    SensorCalibration("CAM_FRONT", (1.72201, 0.00475, 1.49491),
                      (0.50772, -0.49734, 0.49837, -0.49648), 1252.813, (826.588, 469.985)),
    SensorCalibration("CAM_FRONT_RIGHT", (1.58083, -0.49908, 1.51749),
                      (0.20335, -0.19146, 0.67857, -0.67936), 1256.749, (817.789, 451.954)),
    SensorCalibration("CAM_BACK_RIGHT", (1.05945, -0.46720, 1.55051),
                      (0.13819, -0.13797, -0.68933, 0.69763), 1249.963, (825.377, 462.548)),
    SensorCalibration("CAM_BACK", (0.05525, 0.01079, 1.56794),
                      (0.50680, -0.49776, -0.49878, 0.49659), 796.891, (857.777, 476.885)),
    SensorCalibration("CAM_BACK_LEFT", (1.04852, 0.48306, 1.56210),
                      (0.70486, -0.69073, -0.11209, 0.11617), 1254.986, (829.577, 467.168)),
    SensorCalibration("CAM_FRONT_LEFT", (1.57526, 0.50052, 1.50696),
                      (0.68121, -0.66875, 0.21017, -0.21108), 1257.863, (827.241, 450.915)),
    SensorCalibration("LIDAR_TOP", (0.985793, 0.0, 1.84019),
                      (0.70675, -0.01530, 0.01740, -0.70708)),
)


def normalised_rig(rig: tuple[SensorCalibration, ...]) -> tuple[SensorCalibration, ...]:
    """The rig with unit quaternions: published values are rounded to five decimals."""
    return tuple(
        SensorCalibration(
            c.channel,
            c.translation,
            as_rotation(np.asarray(c.rotation) / np.linalg.norm(c.rotation)),
            c.focal,
            c.principal,
        )
        for c in rig
    )


# The HDL-32E spins at 20 Hz (nuScenes data page): a sweep lasts 50 ms. A sweep's timestamp is
# the time of its last column: the cameras of a key frame are triggered 43 to 0 ms before it
# as the beam crosses them (CAMERA_TRIGGER_OFFSET_US), so the key frame's sweep holds them all.
LIDAR_HZ = 20.0


def lidar_column_seconds(azimuth_steps: int) -> np.ndarray:
    """Firing time of each column minus the sweep's timestamp (seconds, <= 0), firing order."""
    return (np.arange(azimuth_steps) + 1 - azimuth_steps) / (azimuth_steps * LIDAR_HZ)


def lidar_start_azimuth(lidar: SensorCalibration, front_camera: SensorCalibration, azimuth_steps: int) -> float:
    """Azimuth (LIDAR frame, radians) of a sweep's first column.

    The beam points along CAM_FRONT's optical axis at the camera's trigger time and turns
    clockwise at 2 pi per sweep; the first column fires one sweep (minus a column) before
    the sweep's timestamp.
    """
    axis_ego = quat_to_matrix(np.asarray(front_camera.rotation))[:, 2]
    camera_azimuth_ego = np.arctan2(axis_ego[1], axis_ego[0])
    first_column = lidar_column_seconds(azimuth_steps)[0]
    trigger = CAMERA_TRIGGER_OFFSET_US[front_camera.channel] / 1e6
    azimuth_ego = camera_azimuth_ego + 2.0 * np.pi * (trigger - first_column) * LIDAR_HZ
    direction = quat_to_matrix(np.asarray(lidar.rotation)).T @ np.array([np.cos(azimuth_ego), np.sin(azimuth_ego), 0.0])
    return float(np.arctan2(direction[1], direction[0]))


# A calibration is an estimate: the true extrinsics differ from the calibrated_sensor record by a
# residual. Target-based camera and LiDAR extrinsic calibration is typically good to a few tenths
# of a degree and one or two centimetres (our reading of the calibration literature; nuScenes
# publishes no residual): we draw each axis from a normal of these standard deviations,
# truncated at three of them.
CALIBRATION_RESIDUAL_DEG = 0.1
CALIBRATION_RESIDUAL_M = 0.007
RESIDUAL_TRUNCATION = 3.0


def true_calibration(calibration: SensorCalibration, rng: np.random.Generator) -> SensorCalibration:
    """The sensor's true extrinsics: the record's, moved by a random residual.

    The residual rotation (a rotation vector in the sensor frame, each component
    N(0, CALIBRATION_RESIDUAL_DEG) truncated) is applied after the record's rotation;
    the translation moves by N(0, CALIBRATION_RESIDUAL_M) per axis, truncated likewise.
    Intrinsics are unchanged.
    """
    bound = RESIDUAL_TRUNCATION
    angles = np.radians(CALIBRATION_RESIDUAL_DEG) * np.clip(rng.standard_normal(3), -bound, bound)
    offset = CALIBRATION_RESIDUAL_M * np.clip(rng.standard_normal(3), -bound, bound)
    angle = np.linalg.norm(angles)
    residual = np.concatenate([[np.cos(angle / 2)], np.sinc(angle / (2 * np.pi)) / 2 * angles])
    rotation = quat_multiply(np.asarray(calibration.rotation, np.float64), residual)
    return dataclasses.replace(
        calibration,
        translation=as_translation(np.asarray(calibration.translation) + offset),
        rotation=as_rotation(rotation / np.linalg.norm(rotation)),
    )
