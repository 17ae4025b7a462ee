"""A ring of cameras on the ego vehicle, and the overlap rule used throughout sianms.

THE overlap definition: a box is in the overlap region when its centre, in front of the
camera, projects inside the images of both cameras of a contiguous pair. Contiguous
pairs are neighbours in the rig's clockwise order (see :class:`CameraRig`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from sianms_cli.errors import SianmsError
from sianms_cli.geometry.transforms import make_transform


@dataclass(frozen=True, eq=False)
class CameraRig:
    """Cameras ordered clockwise seen from above, starting from the most frontal one.

    The order is by the azimuth of the optical axes in the ego frame (measured
    counter-clockwise from ego +x), decreasing, starting from the camera whose axis is
    closest to straight ahead (on a tie, the one on the left). For nuScenes this is
    FRONT, FRONT_RIGHT, BACK_RIGHT, BACK, BACK_LEFT, FRONT_LEFT. Construction always
    reorders the cameras into this order; the arrays are stored read-only.

    Attributes:
        channels: (C,) channel names, unique.
        intrinsics: (C, 3, 3) camera matrices.
        cam_to_ego: (C, 4, 4) camera-to-ego transforms (``p_ego = T p_cam``).
        image_sizes: (C, 2) int64 image sizes [W, H] in pixels.
    """

    channels: tuple[str, ...]
    intrinsics: np.ndarray
    cam_to_ego: np.ndarray
    image_sizes: np.ndarray
    azimuths: np.ndarray = field(init=False, repr=False)
    ego_to_cam: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        channels = tuple(str(name) for name in self.channels)
        count = len(channels)
        if len(set(channels)) != count:
            raise SianmsError(f"camera channels must be unique, got {list(channels)}")
        intrinsics = np.asarray(self.intrinsics, dtype=np.float64)
        cam_to_ego = np.asarray(self.cam_to_ego, dtype=np.float64)
        sizes = np.asarray(self.image_sizes, dtype=np.float64)
        for name, array, shape in (
            ("intrinsics", intrinsics, (count, 3, 3)),
            ("cam_to_ego", cam_to_ego, (count, 4, 4)),
            ("image_sizes", sizes, (count, 2)),
        ):
            if array.shape != shape:
                raise SianmsError(
                    f"{name} must have shape {shape} for {count} cameras, got {array.shape}"
                )
        if not np.all(np.isfinite(sizes) & (sizes > 0) & (sizes == np.round(sizes))):
            raise SianmsError(f"image sizes must be positive whole pixels, got {sizes.tolist()}")

        axes = cam_to_ego[:, :3, 2]
        azimuths = np.arctan2(axes[:, 1], axes[:, 0])
        order = _clockwise_order(azimuths)
        ego_to_cam = np.zeros_like(cam_to_ego)
        rotation_t = np.transpose(cam_to_ego[:, :3, :3], (0, 2, 1))
        ego_to_cam[:, :3, :3] = rotation_t
        ego_to_cam[:, :3, 3] = -np.einsum("cij,cj->ci", rotation_t, cam_to_ego[:, :3, 3])
        ego_to_cam[:, 3, 3] = 1.0

        values = {
            "channels": tuple(channels[i] for i in order),
            "intrinsics": intrinsics[order],
            "cam_to_ego": cam_to_ego[order],
            "image_sizes": sizes[order].astype(np.int64),
            "azimuths": azimuths[order],
            "ego_to_cam": ego_to_cam[order],
        }
        for name, value in values.items():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            object.__setattr__(self, name, value)

    @classmethod
    def from_cameras(
        cls,
        channels: Sequence[str],
        intrinsics: np.ndarray,
        cam_to_ego: np.ndarray,
        image_sizes: np.ndarray,
    ) -> CameraRig:
        """Rig from per-camera arrays in any order; the cameras are sorted clockwise.

        Args:
            channels: C channel names.
            intrinsics: (C, 3, 3) camera matrices.
            cam_to_ego: (C, 4, 4) camera-to-ego transforms.
            image_sizes: (C, 2) [W, H] pixels.
        """
        return cls(tuple(channels), intrinsics, cam_to_ego, image_sizes)

    @classmethod
    def from_calibration(
        cls,
        channels: Sequence[str],
        rotations: np.ndarray,
        translations: np.ndarray,
        intrinsics: np.ndarray,
        image_sizes: np.ndarray,
    ) -> CameraRig:
        """Rig from calibrated_sensor records (camera-to-ego rotation and translation).

        Args:
            channels: C channel names.
            rotations: (C, 4) quaternions (w, x, y, z), camera frame in the ego frame.
            translations: (C, 3) camera positions in the ego frame, metres.
            intrinsics: (C, 3, 3) camera matrices.
            image_sizes: (C, 2) [W, H] pixels.
        """
        rotations = np.asarray(rotations, dtype=np.float64).reshape(-1, 4)
        translations = np.asarray(translations, dtype=np.float64).reshape(-1, 3)
        if len(rotations) != len(translations):
            raise SianmsError(
                f"got {len(rotations)} camera rotations but {len(translations)} translations"
            )
        transforms = np.array(
            [make_transform(q, t) for q, t in zip(rotations, translations, strict=True)]
        )
        return cls(tuple(channels), intrinsics, transforms.reshape(-1, 4, 4), image_sizes)

    @property
    def contiguous_pairs(self) -> tuple[tuple[int, int], ...]:
        """Index pairs of neighbouring cameras: (k, k+1 mod C) for C >= 3, ((0, 1),) for
        C == 2, () for fewer cameras."""
        count = len(self.channels)
        if count < 2:
            return ()
        if count == 2:
            return ((0, 1),)
        return tuple((k, (k + 1) % count) for k in range(count))

    @property
    def pair_names(self) -> tuple[str, ...]:
        """Names of :attr:`contiguous_pairs`, e.g. ``"CAM_FRONT|CAM_FRONT_RIGHT"``."""
        return tuple(f"{self.channels[a]}|{self.channels[b]}" for a, b in self.contiguous_pairs)

    def inside_cameras(self, points_ego: np.ndarray) -> np.ndarray:
        """Which cameras see each point (ignoring occlusion).

        Args:
            points_ego: (N, 3) points in the ego frame, metres.

        Returns:
            (N, C) bool: depth > 0 in the camera and the projection satisfies
            0 <= u < W and 0 <= v < H.
        """
        points_ego = np.asarray(points_ego, dtype=np.float64).reshape(-1, 3)
        points_cam = (
            np.einsum("cij,nj->cni", self.ego_to_cam[:, :3, :3], points_ego)
            + self.ego_to_cam[:, None, :3, 3]
        )
        projected = np.einsum("cij,cnj->cni", self.intrinsics, points_cam)
        depth = points_cam[..., 2]
        in_front = depth > 0
        safe_z = np.where(in_front, projected[..., 2], 1.0)
        u = projected[..., 0] / safe_z
        v = projected[..., 1] / safe_z
        width = self.image_sizes[:, 0, None]
        height = self.image_sizes[:, 1, None]
        inside = in_front & (u >= 0) & (u < width) & (v >= 0) & (v < height)
        return inside.T

    def overlap_pairs(self, points_ego: np.ndarray) -> np.ndarray:
        """Which contiguous pairs see each point with both cameras.

        Args:
            points_ego: (N, 3) points (box centres) in the ego frame.

        Returns:
            (N, P) bool, columns in the order of :attr:`contiguous_pairs`.
        """
        inside = self.inside_cameras(points_ego)
        pairs = np.array(self.contiguous_pairs, dtype=np.int64).reshape(-1, 2)
        return inside[:, pairs[:, 0]] & inside[:, pairs[:, 1]]

    def in_overlap(self, points_ego: np.ndarray) -> np.ndarray:
        """THE overlap rule: the point is seen by both cameras of some contiguous pair.

        Args:
            points_ego: (N, 3) points (box centres) in the ego frame.

        Returns:
            (N,) bool.
        """
        return np.any(self.overlap_pairs(points_ego), axis=1)


def _clockwise_order(azimuths: np.ndarray) -> np.ndarray:
    """Indices sorting cameras clockwise (decreasing azimuth) from the most frontal one."""
    if len(azimuths) == 0:
        return np.zeros(0, dtype=np.int64)
    first = np.lexsort((-azimuths, np.abs(azimuths)))[0]
    clockwise_offset = np.mod(azimuths[first] - azimuths, 2 * np.pi)
    return np.argsort(clockwise_offset, kind="stable")
