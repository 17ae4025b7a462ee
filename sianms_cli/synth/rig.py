"""The nuScenes sensor rig: six cameras and the top LiDAR with their real calibrations.

Values are calibrated_sensor records of two public nuScenes logs (see
``shared/reference/nuscenes.md`` §4): set A from an n015 vehicle (Singapore), set B from
an n008 vehicle (Boston). Images are 1600 x 900; a scaled image keeps the optical
geometry by scaling the intrinsic matrix. Camera trigger offsets relative to the LiDAR
keyframe time come from a real n008 keyframe (reference §2): the spinning LiDAR fires
each camera as its beam crosses the camera's field of view.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
            tuple(float(v) for v in np.asarray(c.rotation) / np.linalg.norm(c.rotation)),
            c.focal,
            c.principal,
        )
        for c in rig
    )
