"""A Velodyne HDL-32E (nuScenes LIDAR_TOP) ray caster.

One sweep fires 32 beams per azimuth column; columns advance clockwise seen from above,
as the sensor spins. Points are stored column by column in firing order (azimuth major,
beams by ascending elevation minor), as in nuScenes .pcd.bin files.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sianms_cli.synth import shapes
from sianms_cli.synth.raycast import intersect_ground, intersect_parts
from sianms_cli.synth.shapes import Parts

# HDL-32E manual: 32 lasers from -30.67 to +10.67 degrees, evenly spaced (~1.33 degrees).
HDL32E_ELEVATIONS_DEG = np.linspace(-30.67, 10.67, 32)

# Diffuse reflectivity at 905 nm by material: licence plates, lamps and retro-reflective
# bands return far more than paint; tyres, glass and dark plastic return little.
MATERIAL_REFLECTIVITY = np.array([
    0.10,  # paint
    0.10,  # paint2
    0.05,  # greenhouse
    0.03,  # tyre
    0.60,  # headlight
    0.60,  # taillight
    0.95,  # plate
    0.05,  # trim
    0.25,  # metal
    0.08,  # cloth
    0.10,  # skin
    0.05,  # hair
    0.20,  # cone
    0.90,  # reflector
    0.15,  # concrete
    0.40,  # barrier stripes
    0.12,  # facade
], np.float64)
assert len(MATERIAL_REFLECTIVITY) == len(shapes.MATERIALS)


@dataclass(frozen=True)
class LidarScan:
    """One sweep.

    points (N,5) float32 in the LIDAR frame: x, y, z (metres), intensity (0..255, integer
    valued), ring index (0..31, index into HDL32E_ELEVATIONS_DEG); owner (N,) int32 object
    index of the surface hit, -1 for the ground and scenery.
    """

    points: np.ndarray
    owner: np.ndarray


def beam_directions(azimuth_steps: int, start_azimuth: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit ray directions in the LIDAR frame, (azimuth_steps * 32, 3), firing order, and the
    ring index of each ray (R,). Column k points at azimuth start - 2 pi k / steps (radians
    from the LIDAR x axis, counter-clockwise positive; the sensor spins clockwise)."""
    az = start_azimuth - 2.0 * np.pi * np.arange(azimuth_steps) / azimuth_steps
    el = np.radians(HDL32E_ELEVATIONS_DEG)
    ca, sa = np.cos(az)[:, None], np.sin(az)[:, None]
    ce, se = np.cos(el)[None, :], np.sin(el)[None, :]
    dirs = np.stack([ca * ce, sa * ce, np.broadcast_to(se, ca.shape[:1] + se.shape[1:])], axis=-1)
    ring = np.broadcast_to(np.arange(len(el)), (azimuth_steps, len(el)))
    return dirs.reshape(-1, 3), ring.reshape(-1)


def _tile_order(columns: int, beams: int, tile_columns: int = 4, tile_beams: int = 8) -> np.ndarray:
    """Permutation of the firing-order rays grouping them in tiles of tile_columns x
    tile_beams neighbouring rays (tile by tile, firing order within a tile)."""
    k, b = np.meshgrid(np.arange(columns), np.arange(beams), indexing="ij")
    key = (k // tile_columns) * -(-beams // tile_beams) + b // tile_beams
    return np.lexsort((b.ravel(), k.ravel(), key.ravel()))


def _keep_probability(cos_incidence, reflectivity, rng_m, max_range, dropout):
    """Probability that a return is reported: a base dropout, more at grazing incidence,
    at long range and for weak (dark, oblique, distant) returns."""
    grazing = np.clip((0.2 - cos_incidence) / 0.2, 0.0, 1.0) * 0.9
    far = 0.3 * (rng_m / max_range) ** 2
    signal = reflectivity * cos_incidence / np.maximum(rng_m / 10.0, 1.0) ** 2
    # Weak returns fade out at the HDL-32E's usable range (70-100 m, nuScenes sensor page):
    # a tyre (0.03) seen head-on near 87 m, paint (0.1) at 70 degrees incidence near 92 m.
    weak = np.clip((0.0004 - signal) / 0.0004, 0.0, 1.0)
    return (1.0 - dropout) * (1.0 - grazing) * (1.0 - far) * (1.0 - weak)


def scan_lidar(parts: Parts, lidar_to_world, rng: np.random.Generator, ground_reflectivity,
               azimuth_steps: int = 1084, max_range: float = 100.0, range_noise_std: float = 0.02,
               dropout: float = 0.05, min_range: float = 0.05,
               start_azimuth: float | None = None) -> LidarScan:
    """Cast one HDL-32E sweep against the ground plane z = 0 and all parts.

    parts: global frame; lidar_to_world (4,4) LIDAR sensor to global; rng: the only source
    of randomness (start azimuth when not given, range noise, dropouts, intensity noise);
    ground_reflectivity(xy (P,2) global metres) -> (P,) reflectivity in [0, 1] (lane
    markings high); azimuth_steps columns per revolution; returns beyond max_range or
    closer than min_range (metres) are lost; range_noise_std metres of Gaussian noise along
    the ray; dropout: base probability of a lost return (more are lost at grazing
    incidence, at long range and for weak returns). Intensity = 255 * reflectivity *
    cos(incidence), with 5 % multiplicative noise, rounded.
    """
    lidar_to_world = np.asarray(lidar_to_world, np.float64)
    rotation, origin = lidar_to_world[:3, :3], lidar_to_world[:3, 3]
    if start_azimuth is None:
        start_azimuth = float(rng.uniform(-np.pi, np.pi))
    dirs_lidar, ring = beam_directions(azimuth_steps, start_azimuth)
    dirs = dirs_lidar @ rotation.T

    t_ground = intersect_ground(origin, dirs, t_max=max_range)
    # Cast in compact tiles of 4 columns x 8 beams so that each bundle's cone is narrow,
    # and stop every ray at the ground: far parts behind the ground are never tested.
    tiles = _tile_order(azimuth_steps, len(HDL32E_ELEVATIONS_DEG))
    t_part, part, normal = (np.empty(len(dirs)), np.empty(len(dirs), np.int64), np.empty((len(dirs), 3)))
    t_part[tiles], part[tiles], normal[tiles], _ = intersect_parts(
        origin, dirs[tiles], parts, t_max=np.minimum(t_ground[tiles], max_range), bundle=32)
    on_part = t_part < t_ground
    t = np.where(on_part, t_part, t_ground)
    hit = np.isfinite(t) & (t >= min_range)

    idx = np.nonzero(hit)[0]
    on_part = on_part[idx]
    t = t[idx]
    part_hit = np.where(on_part, part[idx], 0)
    normals = np.where(on_part[:, None], normal[idx], np.array([0.0, 0.0, 1.0]))
    cos_inc = np.abs(np.einsum("ij,ij->i", normals, dirs[idx]))
    reflect = np.empty(len(idx))
    reflect[on_part] = MATERIAL_REFLECTIVITY[parts.material[part_hit[on_part]]] if on_part.any() else 0.0
    ground = ~on_part
    if ground.any():
        xy = origin[:2] + t[ground, None] * dirs[idx[ground], :2]
        reflect[ground] = np.clip(ground_reflectivity(xy), 0.0, 1.0)

    keep = rng.uniform(size=len(idx)) < _keep_probability(cos_inc, reflect, t, max_range, dropout)
    noisy = t + rng.normal(0.0, range_noise_std, len(idx))
    gain = np.exp(rng.normal(0.0, 0.05, len(idx)))
    keep &= noisy >= min_range

    idx, t_noisy = idx[keep], noisy[keep]
    intensity = np.clip(np.round(255.0 * reflect[keep] * cos_inc[keep] * gain[keep]), 0, 255)
    xyz = dirs_lidar[idx] * t_noisy[:, None]
    points = np.column_stack([xyz, intensity, ring[idx]]).astype(np.float32)
    owner = np.where(on_part[keep], parts.owner[part_hit[keep]] if len(parts) else -1, -1)
    return LidarScan(points=points, owner=owner.astype(np.int32))
