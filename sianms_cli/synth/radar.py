"""How many radar returns fall on each object at a key frame: nuScenes' ``num_radar_pts``.

The nuScenes car carries five Continental ARS 408 radars (front, both front corners facing
sideways, both rear corners; the n015 extrinsics; docs/synthetic_world.md#radar-returns). Each
scans a near field of ±45° out to 70 m and a far field of ±9° out to 250 m (Continental's
ARS 408-21 figures). An object in any radar's field returns a number of clusters whose mean
falls with range as nuScenes' Fig. 13-14 maxima do (40 returns at 10 m, 10 at 50 m: mean ∝
range^-0.861), grows with the object's radar cross-section (vehicles far above people and
cones), and shrinks with occlusion down to a floor: 77 GHz waves reach a hidden car under and
around the one in front, which is why nuScenes keeps annotations that hold radar returns and no
LiDAR point. The count is Poisson about a mean that itself varies from reading to reading
(gamma-distributed, mean 1: an object's radar cross-section swings by tens of dB with aspect and
multipath), so a few readings bring many returns and many bring none, as nuScenes' do.

No radar files are written. The count decides which ground-truth boxes the devkit's evaluation
keeps (``num_lidar_pts + num_radar_pts > 0``): in val, a fifth of the in-range boxes without a
LiDAR point hold a radar return and stay. Objects are sighted, and so annotated, by the LiDAR
alone (``generate.SINGLE_POINT_SIGHTING_RANGE`` says why).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

RADAR_MOUNTS = np.array([
    (3.412, 0.0, 0.0),  # RADAR_FRONT: x, y (m, ego frame), yaw (degrees)
    (2.422, 0.8, 88.0),  # RADAR_FRONT_LEFT
    (2.422, -0.8, -91.0),  # RADAR_FRONT_RIGHT
    (-0.562, 0.628, 174.0),  # RADAR_BACK_LEFT
    (-0.562, -0.618, -176.0),  # RADAR_BACK_RIGHT
])
"""The Set A (n015) car's radar extrinsics, as published in public code; yaw only."""
NEAR_FIELD = (45.0, 70.0)  # half angle (degrees), range (m)
FAR_FIELD = (9.0, 250.0)

RANGE_EXPONENT = np.log(40 / 10) / np.log(50 / 10)
"""Mean returns fall as range^-0.861: nuScenes' most-returning objects give 40 at 10 m and 10 at
50 m (paper SM Fig. 13-14)."""
NEAREST_RANGE = 5.0  # metres: closer objects fill the beam and return no more than at 5 m

RETURNS_AT_10_M = {
    "car": 1.0,
    "truck": 2.0,
    "bus": 2.5,
    "trailer": 2.0,
    "construction": 2.0,
    "motorcycle": 0.4,
    "bicycle": 0.3,
    "pedestrian": 0.2,
    "barrier": 0.3,
    "traffic_cone": 0.1,
}
"""Mean returns of a fully visible object 10 m away, by shape kind, before RETURNS_SCALE: ordered
as the kinds' radar cross-sections are (trucks and buses ~20 dBsm, cars ~10, two-wheelers and
people ~0 to -5, plastic cones less; our estimate). RETURNS_SCALE sets the level."""
RETURNS_SCALE = 3.0
"""With RETURNS_DISPERSION, set so that, as in val, 61.2 % of the boxes inside the devkit's class
ranges hold no radar return (docs/synthetic_world.md#nuscenes-figures), while the annotations carry as many returns on
average as the mini's, 0.85 (nuscenes-devkit#219): 61.5 % and 0.84 on seed 11's 40 scenes."""
RETURNS_DISPERSION = 0.9
"""Shape of the gamma law of each reading's mean (1: exponential). Poisson counts about fixed
means matched the zero share at a scale of 1.9 and then carried 0.55 returns per annotation, not
nuScenes' 0.85: no fixed mean gives both many empty readings and a long tail (40 returns on a
near bus). Shape 1 with scale 2.75 gave 61.5 % and 0.79 on the 40 scenes."""
OCCLUDED_EXPOSURE = 0.4
"""Share of the returns a wholly occluded object still gives (waves under and around the
occluder). Set so that, of the in-range boxes without a LiDAR point, about as many hold a radar
return as in val, (12.01 - 9.43) / 12.01 = 21 %: 23 % on seed 11's 40 scenes
(0.5 gave 19 % under Poisson counts, 25 % with the gamma swing)."""


def in_radar_field(xy: np.ndarray) -> np.ndarray:
    """(...,) bool: ego-frame points (..., 2) inside any radar's near or far field."""
    offset = xy[..., None, :] - RADAR_MOUNTS[:, :2]
    distance = np.hypot(offset[..., 0], offset[..., 1])
    bearing = np.degrees(np.arctan2(offset[..., 1], offset[..., 0])) - RADAR_MOUNTS[:, 2]
    off_axis = np.abs((bearing + 180.0) % 360.0 - 180.0)
    near = (off_axis <= NEAR_FIELD[0]) & (distance <= NEAR_FIELD[1])
    far = (off_axis <= FAR_FIELD[0]) & (distance <= FAR_FIELD[1])
    return (near | far).any(axis=-1)


def returns_at_10_m(kinds: ArrayLike) -> np.ndarray:
    """(N,) RETURNS_AT_10_M of each object's shape kind (N,)."""
    names, inverse = np.unique(np.asarray(kinds, dtype=str), return_inverse=True)
    return np.array([RETURNS_AT_10_M[name] for name in names], dtype=np.float64)[inverse.reshape(-1)]


def expected_returns(strength: np.ndarray, xy: np.ndarray, unoccluded: np.ndarray) -> np.ndarray:
    """(...,) mean radar returns of objects of :func:`returns_at_10_m` ``strength`` at ego-frame
    ``xy`` (..., 2), with ``unoccluded`` (...,) the share of their pixels in the cameras' images
    that nothing nearer hides (NaN: not imaged)."""
    distance = np.maximum(np.hypot(xy[..., 0], xy[..., 1]), NEAREST_RANGE)
    visible = np.clip(np.nan_to_num(unoccluded, nan=0.0), 0.0, 1.0)
    exposure = OCCLUDED_EXPOSURE + (1.0 - OCCLUDED_EXPOSURE) * visible
    mean = RETURNS_SCALE * strength * (10.0 / distance) ** RANGE_EXPONENT * exposure
    return np.where(in_radar_field(xy), mean, 0.0)


def radar_returns(rng: np.random.Generator, strength: np.ndarray, xy: np.ndarray,
                  unoccluded: np.ndarray) -> np.ndarray:
    """(...,) int64 radar returns drawn for each object: Poisson about :func:`expected_returns`
    times a gamma draw of mean 1 and shape ``RETURNS_DISPERSION``."""
    mean = expected_returns(strength, xy, unoccluded)
    swing = rng.gamma(RETURNS_DISPERSION, 1.0 / RETURNS_DISPERSION, size=mean.shape)
    return rng.poisson(mean * swing).astype(np.int64)
