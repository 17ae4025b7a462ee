"""Real nuScenes calibration (docs/synthetic_world.md#rig, set A: log n015, scene-0061)."""

from __future__ import annotations

import numpy as np
import pytest

from sianms_cli.geometry.camera_ring import CameraRig

# channel: (translation x, y, z), (rotation w, x, y, z), fx = fy, cx, cy. CAM_FRONT at full
# precision; the other cameras as the reference table gives them (5 decimals).
SET_A_CAMERAS = {
    "CAM_FRONT": (
        (1.70079, 0.01595, 1.51096),
        (0.4998015430569128, -0.5030316162024876, 0.4997798114386805, -0.49737083824542755),
        1266.417203046554,
        816.2670197447984,
        491.50706579294757,
    ),
    "CAM_FRONT_RIGHT": (
        (1.55085, -0.49340, 1.49575),
        (0.20603, -0.20269, 0.68245, -0.67136),
        1260.847,
        807.968,
        495.334,
    ),
    "CAM_BACK_RIGHT": (
        (1.01488, -0.48057, 1.56240),
        (0.12281, -0.13240, -0.70043, 0.69050),
        1259.514,
        807.253,
        501.196,
    ),
    "CAM_BACK": (
        (0.02833, 0.00345, 1.57910),
        (0.50379, -0.49740, -0.49419, 0.50455),
        809.221,
        829.220,
        481.778,
    ),
    "CAM_BACK_LEFT": (
        (1.03569, 0.48480, 1.59097),
        (0.69242, -0.70316, -0.11648, 0.11203),
        1256.741,
        792.113,
        492.776,
    ),
    "CAM_FRONT_LEFT": (
        (1.52388, 0.49463, 1.50933),
        (0.67573, -0.67363, 0.21214, -0.21123),
        1272.598,
        826.615,
        479.752,
    ),
}
SET_A_IMAGE_SIZE = (1600, 900)
SET_A_LIDAR_ROTATION = (
    0.7077955119163518,
    -0.006492242056004365,
    0.010646214713995808,
    -0.7063073142877817,
)
SET_A_EGO_TRANSLATION = (411.3039349319818, 1180.8903791765097, 0.0)
SET_A_EGO_ROTATION = (
    0.5720320396729045,
    -0.0016977771610471074,
    0.011798001930183783,
    -0.8201446642457809,
)


def intrinsic_matrix(f: float, cx: float, cy: float) -> np.ndarray:
    return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])


def set_a_rig(channels: list[str]) -> CameraRig:
    """Set A rig built from the cameras in the given (any) order."""
    records = [SET_A_CAMERAS[name] for name in channels]
    return CameraRig.from_calibration(
        channels,
        rotations=np.array([r[1] for r in records]),
        translations=np.array([r[0] for r in records]),
        intrinsics=np.array([intrinsic_matrix(*r[2:]) for r in records]),
        image_sizes=np.array([SET_A_IMAGE_SIZE] * len(records)),
    )


@pytest.fixture(scope="session")
def nuscenes_rig() -> CameraRig:
    # Deliberately not in ring order: the rig must sort itself.
    return set_a_rig(
        [
            "CAM_BACK",
            "CAM_FRONT_LEFT",
            "CAM_FRONT",
            "CAM_BACK_RIGHT",
            "CAM_BACK_LEFT",
            "CAM_FRONT_RIGHT",
        ]
    )


@pytest.fixture(scope="session")
def set_a_cameras() -> dict:
    """channel -> (translation, rotation, f, cx, cy) of the Set A calibration."""
    return SET_A_CAMERAS


@pytest.fixture(scope="session")
def set_a_ego_pose() -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(rotation, translation) of the ego pose of sample ca9a282c9e77460f8360f564131a8af5."""
    return SET_A_EGO_ROTATION, SET_A_EGO_TRANSLATION


@pytest.fixture(scope="session")
def set_a_lidar_rotation() -> tuple[float, ...]:
    return SET_A_LIDAR_ROTATION
