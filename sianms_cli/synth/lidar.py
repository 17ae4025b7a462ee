"""A Velodyne HDL-32E (nuScenes LIDAR_TOP) ray caster.

One sweep fires 32 beams per azimuth column; columns advance clockwise seen from above,
as the sensor spins. Points are stored column by column in firing order (azimuth major,
beams by ascending elevation minor), as in nuScenes .pcd.bin files, and every column is
complete: a ray that brings no return (sky, dropout) is stored as a point at the sensor's
origin with intensity 0. nuScenes files hold whole columns (their size is always a
multiple of 32 points; issue:nutonomy/nuscenes-devkit#117) and store invalid measurements
at a radius below 0.1 mm (issue:nutonomy/nuscenes-devkit#845), which is why the devkit's
multi-sweep loader drops points within 1 m of the sensor; hence ~34.7k points per sweep.

Candidate (ray, part) pairs come from a raster cull: each part's angular bounding box, as
seen from the sensor, selects the block of columns x beams that can reach it, so a sweep
costs in proportion to the parts' angular size rather than rays x parts.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numba
import numpy as np

from sianms_cli.synth import shapes
from sianms_cli.synth.raycast import T_MIN, intersect_ground, slab_interval
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

_MAX_PAIRS = 200_000  # (ray, part) pairs per chunk of the nearest-hit search: where ties between chunks fall


@dataclass(frozen=True)
class LidarScan:
    """One sweep.

    points (N,5) float32 in the LIDAR frame, one per ray in firing order (N = columns x 32):
    x, y, z (metres), intensity (0..255, integer valued), ring index (0..31, index into
    HDL32E_ELEVATIONS_DEG); owner (N,) int32 object index of the surface hit, -1 for the
    ground and scenery and for no return; returned (N,) bool, False for a ray that brought
    no return (stored as x = y = z = intensity = 0).
    """

    points: np.ndarray
    owner: np.ndarray
    returned: np.ndarray


def beam_directions(azimuth_steps: int, start_azimuth: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit ray directions in the LIDAR frame, (azimuth_steps * 32, 3), firing order, and the
    ring index of each ray (R,). Column k points at azimuth start - 2 pi k / steps (radians
    from the LIDAR x axis, counter-clockwise positive; the sensor spins clockwise)."""
    az = column_azimuths(azimuth_steps, start_azimuth)
    el = np.radians(HDL32E_ELEVATIONS_DEG)
    ca, sa = np.cos(az)[:, None], np.sin(az)[:, None]
    ce, se = np.cos(el)[None, :], np.sin(el)[None, :]
    dirs = np.stack([ca * ce, sa * ce, np.broadcast_to(se, ca.shape[:1] + se.shape[1:])], axis=-1)
    ring = np.broadcast_to(np.arange(len(el)), (azimuth_steps, len(el)))
    return dirs.reshape(-1, 3), ring.reshape(-1)


def column_azimuths(azimuth_steps: int, start_azimuth: float) -> np.ndarray:
    """Azimuth of each column in the LIDAR frame (radians), firing order: clockwise."""
    return start_azimuth - 2.0 * np.pi * np.arange(azimuth_steps) / azimuth_steps


@numba.njit(cache=True)
def _turn_columns(rotations: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Directions dirs (C,B,3) of each column turned by that column's rotation (C,3,3).

    Each component sums its three products as (x + z) + y, the order numpy's einsum took on
    x86-64 (its SIMD kernel adds the first and third lanes, then the second), so the datasets
    written with einsum are written again to the bit, in a seventieth of the time; no fused
    multiply-add (numba contracts nothing unless told to).
    """
    out = np.empty(dirs.shape)
    for c in range(dirs.shape[0]):
        for b in range(dirs.shape[1]):
            x, y, z = dirs[c, b, 0], dirs[c, b, 1], dirs[c, b, 2]
            for i in range(3):
                out[c, b, i] = (rotations[c, i, 0] * x + rotations[c, i, 2] * z) + rotations[c, i, 1] * y
    return out


def _level_frame(lidar_to_world: np.ndarray) -> np.ndarray:
    """(3,3) rotation of the level frame at the sensor: z up, x along the LIDAR x axis's heading.

    Parts are yaw-only cuboids, so their angular extent is simple to bound in this frame."""
    yaw = np.arctan2(lidar_to_world[1, 0], lidar_to_world[0, 0])
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _direction_margins(dirs: np.ndarray, level: np.ndarray, start_azimuth: float, azimuth_steps: int):
    """Largest azimuth and elevation differences (radians) between the rays (R,3) global,
    firing order, seen in the level frame and their nominal column azimuth and beam
    elevation: the sensor's tilt and its turn during the sweep. The cull widens by these."""
    d = dirs @ level
    beams = len(HDL32E_ELEVATIONS_DEG)
    az = np.arctan2(d[:, 1], d[:, 0]) - np.repeat(column_azimuths(azimuth_steps, start_azimuth), beams)
    el = np.arcsin(np.clip(d[:, 2], -1.0, 1.0)) - np.tile(np.radians(HDL32E_ELEVATIONS_DEG), azimuth_steps)
    return float(np.abs(np.angle(np.exp(1j * az))).max()) + 1e-6, float(np.abs(el).max()) + 1e-6


def _angular_bounds(parts: Parts, origin: np.ndarray, level: np.ndarray, inflate: np.ndarray):
    """Azimuth interval (centre, half width) and elevation interval (low, high) of each part,
    seen from ``origin`` in the level frame, radians; each part's box grown by ``inflate`` (M,)
    metres on every side. A part whose grown footprint holds the origin spans every azimuth."""
    rel = parts.center - origin
    cx, cy = rel @ level[:, 0], rel @ level[:, 1]
    yaw = parts.yaw - np.arctan2(level[1, 0], level[0, 0])
    half = parts.half_size + inflate[:, None]
    c, s = np.cos(yaw), np.sin(yaw)
    # Corners of the footprint in the level frame, (M, 4).
    sx, sy = np.array([1.0, 1.0, -1.0, -1.0]), np.array([1.0, -1.0, -1.0, 1.0])
    lx, ly = sx[None, :] * half[:, :1], sy[None, :] * half[:, 1:2]
    x = cx[:, None] + c[:, None] * lx - s[:, None] * ly
    y = cy[:, None] + s[:, None] * lx + c[:, None] * ly
    az_center = np.arctan2(cy, cx)
    offset = np.angle(np.exp(1j * (np.arctan2(y, x) - az_center[:, None])))
    lo, hi = offset.min(axis=1), offset.max(axis=1)
    # Horizontal distance from the origin to the footprint (0 inside) and to its farthest corner.
    ox, oy = c * cx + s * cy, -s * cx + c * cy  # the footprint's centre in its own frame, negated
    near = np.hypot(np.maximum(np.abs(ox) - half[:, 0], 0.0), np.maximum(np.abs(oy) - half[:, 1], 0.0))
    far = np.hypot(x, y).max(axis=1)
    inside = near <= 0.0
    az_mid = np.where(inside, 0.0, az_center + (lo + hi) / 2)
    az_half = np.where(inside, np.pi, (hi - lo) / 2)
    z_lo = rel @ level[:, 2] - half[:, 2]
    z_hi = rel @ level[:, 2] + half[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        el_lo = np.arctan2(z_lo, np.where(z_lo < 0, near, far))
        el_hi = np.arctan2(z_hi, np.where(z_hi > 0, near, far))
    return az_mid, az_half, el_lo, el_hi


def candidate_pairs(parts: Parts, origin: np.ndarray, level: np.ndarray, inflate: np.ndarray,
                    start_azimuth: float, azimuth_steps: int, az_margin: float, el_margin: float,
                    reach: np.ndarray | None = None, t_max: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(ray, part) pairs of one sweep whose ray may hit the part, rays in firing order.

    Each part's angular bounding box (see :func:`_angular_bounds`), widened by the margins
    (radians, see :func:`_direction_margins`), selects a block of columns x
    beams: a raster cull, so the cost follows the parts' angular size, not rays x parts.
    With reach (M,), the nearest any point of each part can be, and t_max (R,), how far each
    ray can reach, a pair whose part lies beyond its ray's reach is left out.
    """
    beams = len(HDL32E_ELEVATIONS_DEG)
    az_mid, az_half, el_lo, el_hi = _angular_bounds(parts, origin, level, inflate)
    step = 2.0 * np.pi / azimuth_steps
    # Column k looks at start - k * step: the interval [mid - half, mid + half] holds k from k_lo.
    k_lo = np.ceil((start_azimuth - az_mid - az_half - az_margin) / step)
    k_hi = np.floor((start_azimuth - az_mid + az_half + az_margin) / step)
    n_col = np.clip(k_hi - k_lo + 1, 0, azimuth_steps).astype(np.int64)
    el = np.radians(HDL32E_ELEVATIONS_DEG)
    b_lo = np.searchsorted(el, el_lo - el_margin, side="left")
    n_beam = np.maximum(np.searchsorted(el, el_hi + el_margin, side="right") - b_lo, 0)
    if reach is None:
        reach, t_max = np.full(len(n_col), -np.inf), np.full(azimuth_steps * beams, np.inf)
    return _raster_pairs(k_lo.astype(np.int64), n_col, b_lo.astype(np.int64), n_beam.astype(np.int64), azimuth_steps,
                         beams, reach, t_max)


@numba.njit(cache=True)
def _raster_pairs(k_lo, n_col, b_lo, n_beam, azimuth_steps, beams, reach, t_max):
    """(ray, part) of each part's block of ``n_col`` columns from ``k_lo`` (wrapping around the
    revolution) by ``n_beam`` beams from ``b_lo``: part by part, column by column, beam by beam;
    only pairs whose part's ``reach`` is within the ray's ``t_max``."""
    total = 0
    for m in range(len(n_col)):
        total += n_col[m] * n_beam[m]
    ray = np.empty(total, np.int64)
    part = np.empty(total, np.int64)
    i = 0
    for m in range(len(n_col)):
        for k in range(n_col[m]):
            first = ((k_lo[m] + k) % azimuth_steps) * beams + b_lo[m]
            for b in range(n_beam[m]):
                if reach[m] <= t_max[first + b]:
                    ray[i] = first + b
                    part[i] = m
                    i += 1
    return ray[:i], part[:i]


@dataclass(frozen=True)
class PartMotion:
    """Parts that move while the sensor sweeps: velocity (M,3) global m/s of each part and
    ray_seconds (R,) each ray's firing time minus the sweep's reference time. A ray meets a
    part where the part is when the ray fires: its origin moves by minus the displacement."""

    velocity: np.ndarray
    ray_seconds: np.ndarray

    def shift(self, rr: np.ndarray, pp: np.ndarray) -> np.ndarray:
        """(K,3) displacement of parts pp at the firing times of rays rr."""
        return self.velocity[pp] * self.ray_seconds[rr, None]


def _nearest_hits(ray, part, origins, dirs, parts: Parts, t_max, motion: PartMotion | None):
    """Nearest part hit per ray over candidate (ray, part) pairs.

    origins (R,3) relative to the sweep's reference origin and parts' centres likewise (so
    float32 keeps sub-millimetre precision within the LiDAR's range); motion moves each ray's
    origin by minus its part's displacement (parts that move while the sensor sweeps). Returns
    t (R,) float64 (inf = none), part (R,) (-1 = none) and the unit outward normal (R,3) of the
    face hit, global frame; the face is found for the winning pairs only (the slab entered
    last, as raycast.intersect_boxes does).
    """
    half = parts.half_size.astype(np.float32)
    c, s = np.cos(parts.yaw), np.sin(parts.yaw)
    moving = motion is not None
    velocity = motion.velocity if motion is not None else np.zeros((0, 3))
    seconds = motion.ray_seconds if motion is not None else np.zeros(0)
    t_best, part_best, face = _nearest_entries(ray, part, origins, dirs, parts.center, half, c, s, moving, velocity,
                                               seconds, t_max, np.float32(T_MIN), _MAX_PAIRS)
    return t_best.astype(np.float64), part_best, _face_normals(face, part_best, c, s)


@numba.njit(cache=True, error_model="numpy")
def _nearest_entries(ray, part, origins, dirs, center, half, cos, sin, moving, velocity, seconds, t_max, t_min,
                     chunk):
    """Per ray, the float32 parameter where it enters its nearest part of the pairs, that part,
    and the face it enters through (see :func:`_face_normals`; -1 for none).

    The arithmetic of :func:`_pair_slabs`, pair by pair: the ray's origin and direction in
    the part's frame in float64, rounded to float32, then :func:`raycast.slab_interval` in
    float32 with numpy's NaN-propagating minimum and maximum (no fused multiply-add: numba
    contracts nothing unless told to), so the result is numpy's to the bit. Pairs are taken in
    chunks of ``chunk``, as the numpy version of this search took them to bound its memory: of
    equally near parts of one ray, the last pair of the first chunk holding the nearest entry
    wins, so the datasets it wrote are written again byte for byte. The face is the slab entered
    last, the first of equal ones (numpy's argmax over the slab test's entries).
    """
    n_rays = dirs.shape[0]
    t_best = np.full(n_rays, np.inf, np.float32)
    part_best = np.full(n_rays, -1, np.int64)
    face_best = np.full(n_rays, -1, np.int8)
    chunk_min = np.full(n_rays, np.inf, np.float32)
    entry = np.empty(min(chunk, len(ray)), np.float32)
    face = np.empty(min(chunk, len(ray)), np.int8)
    inf = np.float32(np.inf)
    for start in range(0, len(ray), chunk):
        stop = min(start + chunk, len(ray))
        for i in range(start, stop):
            r, p = ray[i], part[i]
            o0, o1, o2 = origins[r, 0] - center[p, 0], origins[r, 1] - center[p, 1], origins[r, 2] - center[p, 2]
            if moving:
                o0 = o0 - velocity[p, 0] * seconds[r]
                o1 = o1 - velocity[p, 1] * seconds[r]
                o2 = o2 - velocity[p, 2] * seconds[r]
            cp, sp = cos[p], sin[p]
            local_o = (np.float32(cp * o0 + sp * o1), np.float32(cp * o1 - sp * o0), np.float32(o2))
            local_d = (np.float32(cp * dirs[r, 0] + sp * dirs[r, 1]), np.float32(cp * dirs[r, 1] - sp * dirs[r, 0]),
                       np.float32(dirs[r, 2]))
            t_near, t_far, lo0 = _slab(-half[p, 0] - local_o[0], half[p, 0] - local_o[0], local_d[0], -inf, inf)
            t_near, t_far, lo1 = _slab(-half[p, 1] - local_o[1], half[p, 1] - local_o[1], local_d[1], t_near, t_far)
            t_near, t_far, lo2 = _slab(-half[p, 2] - local_o[2], half[p, 2] - local_o[2], local_d[2], t_near, t_far)
            t = t_near if (t_near <= t_far) and (t_near > t_min) and (t_near < t_max[r]) else inf
            entry[i - start] = t
            if t < inf:
                axis = 2 if lo2 > max(lo0, lo1) else (1 if lo1 > lo0 else 0)
                face[i - start] = 2 * axis + (1 if local_d[axis] > 0 else 0)
            if t < chunk_min[r]:
                chunk_min[r] = t
        for i in range(start, stop):
            r, t = ray[i], entry[i - start]
            if t < inf and t == chunk_min[r] and t < t_best[r]:
                part_best[r] = part[i]
                face_best[r] = face[i - start]
        for i in range(start, stop):
            r = ray[i]
            if chunk_min[r] < t_best[r]:
                t_best[r] = chunk_min[r]
            chunk_min[r] = inf
    return t_best, part_best, face_best


def _face_normals(face, part, cos, sin):
    """Global unit outward normal (R,3) of the face each ray entered its part ``part`` (R,) through:
    face (R,) ``2 * axis + 1`` when the ray entered along the part's +axis (through the face at
    -half), ``2 * axis`` along -axis, -1 for no hit (normal zero); cos, sin of the parts' yaw."""
    rays = np.flatnonzero(face >= 0)
    axis = face[rays] // 2
    n_local = np.zeros((len(rays), 3))
    n_local[np.arange(len(rays)), axis] = np.where(face[rays] % 2 == 1, -1.0, 1.0)
    cp, sp = cos[part[rays]], sin[part[rays]]
    normal = np.zeros((len(face), 3))
    normal[rays] = np.column_stack([cp * n_local[:, 0] - sp * n_local[:, 1], sp * n_local[:, 0] + cp * n_local[:, 1],
                                    n_local[:, 2]])
    return normal


@numba.njit(cache=True, error_model="numpy")
def _slab(lower, upper, d, t_near, t_far):
    """One axis of :func:`raycast.slab_interval` (float32), narrowing (t_near, t_far), and its
    entry parameter; the first axis passes (-inf, inf), which leaves its own bounds, as numpy's
    first axis does."""
    inv = np.float32(1.0) / d
    t1, t2 = lower * inv, upper * inv
    lo = _minimum(t1, t2)
    return _maximum(t_near, lo), _minimum(t_far, _maximum(t1, t2)), lo


@numba.njit(cache=True)
def _minimum(a, b):
    """numpy.minimum: NaN if either is NaN."""
    if a != a or b != b:
        return a if a != a else b
    return a if a <= b else b


@numba.njit(cache=True)
def _maximum(a, b):
    """numpy.maximum: NaN if either is NaN."""
    if a != a or b != b:
        return a if a != a else b
    return a if a >= b else b


def _local_rays(rr, pp, origins, dirs, center, c, s, motion):
    """Origins and directions of rays rr in the frames of parts pp (float32 per axis)."""
    o = origins[rr] - center[pp] if motion is None else origins[rr] - center[pp] - motion.shift(rr, pp)
    d = dirs[rr]
    cp, sp = c[pp], s[pp]
    f32 = np.float32
    local_o = ((cp * o[:, 0] + sp * o[:, 1]).astype(f32), (cp * o[:, 1] - sp * o[:, 0]).astype(f32),
               o[:, 2].astype(f32))
    local_d = ((cp * d[:, 0] + sp * d[:, 1]).astype(f32), (cp * d[:, 1] - sp * d[:, 0]).astype(f32),
               d[:, 2].astype(f32))
    return local_o, local_d


def _pair_slabs(rr, pp, origins, dirs, center, half, c, s, motion):
    """raycast.slab_interval of rays rr against parts pp, and the rays' local directions."""
    o, d = _local_rays(rr, pp, origins, dirs, center, c, s, motion)
    h = [half[pp, k] for k in range(3)]
    return slab_interval([-h_k - o_k for h_k, o_k in zip(h, o)], [h_k - o_k for h_k, o_k in zip(h, o)], d), d


@numba.njit(cache=True)
def _cos_incidence(rays, on_part, normal, dirs):
    """|cos| of the angle between each hit ray ``rays`` (N,) and the surface it hit: its part's
    face normal (R,3) where on_part (N,), the ground's (0, 0, 1) elsewhere. The dot product sums
    as (x + z) + y, numpy's einsum's order, as datasets were written with it."""
    cos = np.empty(len(rays))
    for i in range(len(rays)):
        r = rays[i]
        n0, n1, n2 = (normal[r, 0], normal[r, 1], normal[r, 2]) if on_part[i] else (0.0, 0.0, 1.0)
        cos[i] = abs((n0 * dirs[r, 0] + n2 * dirs[r, 2]) + n1 * dirs[r, 1])
    return cos


@numba.njit(cache=True)
def _points_along(origins, dirs, rays, t):
    """Points (N,3) ``t`` (N,) metres along rays ``rays`` (N,) from their origins (R,3):
    ``origins[rays] + t[:, None] * dirs[rays]`` without the gathered copies."""
    points = np.empty((len(rays), 3))
    for i in range(len(rays)):
        r = rays[i]
        for k in range(3):
            points[i, k] = origins[r, k] + t[i] * dirs[r, k]
    return points


@numba.njit(cache=True)
def _ground_points(origin_xy, origins, dirs, rays, t):
    """Global xy (N,2) where rays ``rays`` (N,) meet the ground ``t`` (N,) metres along them;
    origins (R,3) relative to origin_xy (2,) (the arithmetic of ``origin + o + t * d``)."""
    xy = np.empty((len(rays), 2))
    for i in range(len(rays)):
        r = rays[i]
        for k in range(2):
            xy[i, k] = (origin_xy[k] + origins[r, k]) + t[i] * dirs[r, k]
    return xy


# Car windows (the sides of a glazed cabin; its roof is metal) reflect the beam away or let
# it through: they bring no return except near normal incidence (issue:nutonomy/nuscenes-devkit#845:
# no return "when hitting very reflective surfaces such as car windows"; the 10 degree cone is
# our choice).
GLASS_MATERIALS = np.array([shapes.GREENHOUSE])
GLASS_RETURN_COS = np.cos(np.radians(10.0))


def _keep_probability(cos_incidence, reflectivity, rng_m, max_range, dropout, glass):
    """Probability that a return is reported: a base dropout, more at grazing incidence,
    at long range and for weak (dark, oblique, distant) returns; glass (bool) returns only
    near normal incidence."""
    grazing = np.clip((0.2 - cos_incidence) / 0.2, 0.0, 1.0) * 0.9
    far = 0.3 * (rng_m / max_range) ** 2
    signal = reflectivity * cos_incidence / np.maximum(rng_m / 10.0, 1.0) ** 2
    # Weak returns fade out at the HDL-32E's usable range (70-100 m, nuScenes sensor page):
    # a tyre (0.03) seen head-on near 87 m, paint (0.1) at 70 degrees incidence near 92 m.
    weak = np.clip((0.0004 - signal) / 0.0004, 0.0, 1.0)
    specular = glass & (cos_incidence < GLASS_RETURN_COS)
    return (1.0 - dropout) * (1.0 - grazing) * (1.0 - far) * (1.0 - weak) * ~specular


# Rain (a moderate shower of a few mm/h; natural rain rarely exceeds 25 mm/h, Goodin et al.,
# Electronics 8(1):89, 2019). The magnitudes are our own estimates, set from what studies of
# spinning LiDARs in rain report: the number of returns falls with rain, most on wet pavement,
# whose water film mirrors the beam away (Filgueira et al., Measurement 95, 2017, VLP-16), dark
# surfaces lose more than bright ones, and raindrops bring sparse, weak, single returns within a
# few metres of the sensor (Ouster OS1-32 field trial, pathvynt.com "Point cloud filtering for
# rain, dust, and fog": drops at ~3 m, a few per cent of the rays of a sector in a downpour).
RAIN_EXTINCTION_PER_M = 1.0e-3  # beam extinction by drops: ~1/km at a few mm/h, two ways over the range
RAIN_BASE_LOSS = 0.01  # water on the sensor window scatters some pulses of every ray
RAIN_WET_ROAD_LOSS = 0.06  # the road's film of water reflects the beam away
RAIN_DARK_LOSS = 0.04  # wet dark surfaces (tyres, trim, glass, dark paint) at reflectivity 0
RAIN_DARK_REFLECTIVITY = 0.15  # ... fading out at this reflectivity
RAIN_DROP_SHARE = 0.003  # rays whose first return is a raindrop (~100 of a 34.7k-ray sweep)
RAIN_DROP_RANGE_M = (1.0, 5.0)  # where drops return: near, where a drop fills enough of the beam
RAIN_DROP_INTENSITY = (1, 8)  # weak: a drop fills a small part of the beam's footprint
# Road spray: the tyres of moving vehicles throw up a cloud of droplets behind them that
# LiDARs see as clutter trailing the vehicle (a known source of false detections in rain, e.g.
# "Towards robust 3D object detection in rainy conditions", arXiv 2023); its size and density
# are our own estimates.
RAIN_SPRAY_LENGTH_M = 3.0  # the cloud trails this far behind the vehicle's rear
RAIN_SPRAY_HEIGHT_M = 1.0  # from the road up to about the top of the wheels' arches and a little above
RAIN_SPRAY_PER_M = 0.05  # chance per metre of cloud a ray crosses that it reports spray, at full speed
RAIN_SPRAY_FULL_SPEED = 20.0  # m/s (72 km/h); the cloud thickens linearly with speed up to it


@dataclass(frozen=True)
class Spray:
    """Spray clouds behind moving vehicles in rain: boxes (K cuboids, global frame, owner -1)
    and per_metre (K,) the chance per metre crossed that a ray reports the cloud."""

    boxes: Parts
    per_metre: np.ndarray


def spray_behind(center: np.ndarray, yaw: np.ndarray, size_wlh: np.ndarray, speed: np.ndarray) -> Spray:
    """The spray cloud of each of V vehicles: center (V,3) global box centres, yaw (V,), size_wlh
    (V,3) metres, speed (V,) m/s. A box as wide as the vehicle from the road up, behind its rear,
    denser the faster the vehicle goes (none when parked)."""
    behind = size_wlh[:, 1] / 2 + RAIN_SPRAY_LENGTH_M / 2
    middle = center[:, :2] - behind[:, None] * np.column_stack([np.cos(yaw), np.sin(yaw)])
    boxes = Parts(np.column_stack([middle, np.full(len(yaw), RAIN_SPRAY_HEIGHT_M / 2)]),
                  np.column_stack([np.full(len(yaw), RAIN_SPRAY_LENGTH_M / 2), size_wlh[:, 0] / 2,
                                   np.full(len(yaw), RAIN_SPRAY_HEIGHT_M / 2)]),
                  yaw, np.full(len(yaw), -1), np.full(len(yaw), shapes.CONCRETE))
    return Spray(boxes, RAIN_SPRAY_PER_M * np.clip(speed / RAIN_SPRAY_FULL_SPEED, 0.0, 1.0))


def _spray_ranges(spray: Spray, reference: np.ndarray, origins: np.ndarray, dirs: np.ndarray, level: np.ndarray,
                  inflate: float, start_azimuth: float, azimuth_steps: int, az_margin: float, el_margin: float,
                  rng: np.random.Generator) -> np.ndarray:
    """(R,) metres along each ray to the spray it reports (inf for none): a ray crossing a cloud
    for d metres reports it with probability 1 - exp(-per_metre d), at a uniform depth within."""
    boxes = spray.boxes
    ray, box = candidate_pairs(boxes, reference[:3, 3], level, np.full(len(boxes), inflate), start_azimuth,
                               azimuth_steps, az_margin, el_margin)
    c, s = np.cos(boxes.yaw), np.sin(boxes.yaw)
    (t_near, t_far, _), _ = _pair_slabs(ray, box, origins, dirs, boxes.center - reference[:3, 3],
                                        boxes.half_size.astype(np.float32), c, s, None)
    entry = np.maximum(t_near, np.float32(T_MIN)).astype(np.float64)
    crossed = np.maximum(t_far - entry, 0.0)
    reports = rng.uniform(size=len(ray)) < 1.0 - np.exp(-spray.per_metre[box] * crossed)
    depth = entry + rng.uniform(size=len(ray)) * crossed
    ranges = np.full(len(dirs), np.inf)
    np.minimum.at(ranges, ray[reports], depth[reports])
    return ranges


def _rain_keep_probability(cos_incidence, reflectivity, rng_m, max_range, dropout, glass, ground):
    """Probability that a return is reported in rain (see :func:`_keep_probability`): the
    signal is dimmed by the drops along the way and back, and wet road and wet dark surfaces
    lose more returns. Never above the dry probability."""
    transmission = np.exp(-2.0 * RAIN_EXTINCTION_PER_M * rng_m)
    dark = np.clip(1.0 - reflectivity / RAIN_DARK_REFLECTIVITY, 0.0, 1.0)
    loss = RAIN_BASE_LOSS + np.where(ground, RAIN_WET_ROAD_LOSS, RAIN_DARK_LOSS * dark)
    dimmed = _keep_probability(cos_incidence, reflectivity * transmission, rng_m, max_range, dropout, glass)
    return dimmed * (1.0 - loss)


def _add_raindrops(points: np.ndarray, owner: np.ndarray, returned: np.ndarray, origins_lidar: np.ndarray,
                   dirs_lidar: np.ndarray, ray_range: np.ndarray, rng: np.random.Generator) -> None:
    """Replace a few rays' returns by raindrop returns in place: points (R,5) LIDAR frame,
    owner (R,), returned (R,); origins_lidar and dirs_lidar (R,3) each ray's origin and
    direction in the LIDAR frame of the reference time; ray_range (R,) metres to the ray's
    return (inf for none). A drop shows only in front of the surface the ray would have hit;
    drop ranges crowd towards the sensor, where a drop is brightest."""
    n = len(points)
    ray = np.flatnonzero(rng.uniform(size=n) < RAIN_DROP_SHARE)
    near, far = RAIN_DROP_RANGE_M
    distance = np.full(n, np.inf)
    distance[ray] = near + (far - near) * rng.uniform(size=len(ray)) ** 2
    _set_clutter(points, owner, returned, origins_lidar, dirs_lidar, ray[distance[ray] < ray_range[ray]], distance,
                 rng)


def _set_clutter(points: np.ndarray, owner: np.ndarray, returned: np.ndarray, origins_lidar: np.ndarray,
                 dirs_lidar: np.ndarray, ray: np.ndarray, distance: np.ndarray, rng: np.random.Generator) -> None:
    """Make rays ``ray`` (K,) weak returns of water (drops, spray) at ``distance`` (R,) metres
    along them, in place (arrays as :func:`_add_raindrops`)."""
    points[ray, :3] = origins_lidar[ray] + distance[ray, None] * dirs_lidar[ray]
    points[ray, 3] = rng.integers(RAIN_DROP_INTENSITY[0], RAIN_DROP_INTENSITY[1] + 1, len(ray))
    owner[ray] = -1
    returned[ray] = True


def scan_lidar(parts: Parts, lidar_to_world, rng: np.random.Generator, ground_reflectivity,
               azimuth_steps: int = 1084, max_range: float = 100.0, range_noise_std: float = 0.02,
               dropout: float = 0.05, min_range: float = 0.05, start_azimuth: float | None = None,
               column_poses: np.ndarray | None = None, column_seconds: np.ndarray | None = None,
               part_velocity: np.ndarray | None = None, rain_rng: np.random.Generator | None = None,
               spray: Spray | None = None) -> LidarScan:
    """Cast one HDL-32E sweep against the ground plane z = 0 and all parts.

    parts: global frame, posed at the sweep's reference time; lidar_to_world (4,4) LIDAR
    sensor to global at that time: points are expressed in this frame (motion-compensated,
    as nuScenes sweeps are). column_poses (C,4,4): the sensor pose when each column fires
    (default: lidar_to_world, a still sensor); column_seconds (C,) each column's firing time
    minus the reference time and part_velocity (M,3) global m/s: moving parts are where
    they are when the column fires (linear motion), so they smear as on a real sweep.
    rng: the only source of randomness (start azimuth when not given, range noise,
    dropouts, intensity noise); ground_reflectivity(xy (P,2) global metres) -> (P,)
    reflectivity in [0, 1] (lane markings high); azimuth_steps columns per revolution;
    returns beyond max_range or closer than min_range (metres) are lost; range_noise_std
    metres of Gaussian noise along the ray; dropout: base probability of a lost return
    (more are lost at grazing incidence, at long range and for weak returns). Intensity =
    255 * reflectivity * cos(incidence), with 5 % multiplicative noise, rounded.
    rain_rng: when given, the sweep is taken in rain (see :func:`_rain_keep_probability`,
    :func:`_add_raindrops`; returns dimmed by the drops), every rain effect drawn from this
    generator, so ``rng``'s draws and a dry sweep are the same as without rain. spray: in
    rain, the clouds behind moving vehicles (see :func:`spray_behind`; their motion over the
    sweep is neglected, the cloud is a blur anyway).
    """
    reference = np.asarray(lidar_to_world, np.float64)
    if start_azimuth is None:
        start_azimuth = float(rng.uniform(-np.pi, np.pi))
    poses = np.broadcast_to(reference, (azimuth_steps, 4, 4)) if column_poses is None else column_poses
    beams = len(HDL32E_ELEVATIONS_DEG)
    dirs_lidar, ring = beam_directions(azimuth_steps, start_azimuth)
    dirs = _turn_columns(poses[:, :3, :3], dirs_lidar.reshape(azimuth_steps, beams, 3)).reshape(-1, 3)
    column_origins = poses[:, :3, 3] - reference[:3, 3]  # relative to the reference origin
    origins = np.repeat(column_origins, beams, axis=0)
    t_ground = intersect_ground(origins + reference[:3, 3], dirs, t_max=max_range)

    level = _level_frame(reference)
    spread = np.linalg.norm(column_origins, axis=1).max()
    inflate = np.full(len(parts), spread + 1e-3)
    motion = None
    if part_velocity is not None and len(parts):
        assert column_seconds is not None, "moving parts need each column's firing time"
        inflate += np.linalg.norm(part_velocity, axis=1) * np.abs(column_seconds).max()
        motion = PartMotion(np.asarray(part_velocity, np.float64), np.repeat(column_seconds, beams))
    az_margin, el_margin = _direction_margins(dirs, level, start_azimuth, azimuth_steps)
    t_max = np.minimum(t_ground, max_range)
    center = parts.center - reference[:3, 3]
    reach = np.linalg.norm(center, axis=1) - parts.bounding_radius() - inflate
    # Parts beyond the ray's ground hit are never tested.
    ray, part = candidate_pairs(parts, reference[:3, 3], level, inflate, start_azimuth, azimuth_steps,
                                az_margin, el_margin, reach, t_max)
    t_part, part_hit, normal = _nearest_hits(ray, part, origins, dirs, dataclasses.replace(parts, center=center),
                                             t_max.astype(np.float32), motion)
    on_part = t_part < t_ground
    t = np.where(on_part, t_part, t_ground)
    hit = np.isfinite(t) & (t >= min_range)

    idx = np.nonzero(hit)[0]
    on_part = on_part[idx]
    t = t[idx]
    part_hit = np.where(on_part, part_hit[idx], 0)
    cos_inc = _cos_incidence(idx, on_part, normal, dirs)
    reflect = np.empty(len(idx))
    reflect[on_part] = MATERIAL_REFLECTIVITY[parts.material[part_hit[on_part]]] if on_part.any() else 0.0
    ground = ~on_part
    if ground.any():
        xy = _ground_points(reference[:2, 3], origins, dirs, idx[ground], t[ground])
        reflect[ground] = np.clip(ground_reflectivity(xy), 0.0, 1.0)

    glass = np.zeros(len(idx), bool)
    side = np.abs(normal[idx[on_part], 2]) < 0.5
    glass[on_part] = np.isin(parts.material[part_hit[on_part]], GLASS_MATERIALS) & side
    keep_dry = _keep_probability(cos_inc, reflect, t, max_range, dropout, glass)
    keep = rng.uniform(size=len(idx)) < keep_dry
    noisy = t + rng.normal(0.0, range_noise_std, len(idx))
    gain = np.exp(rng.normal(0.0, 0.05, len(idx)))
    keep &= noisy >= min_range
    if rain_rng is not None:
        # Kept with probability wet / dry among the dry survivors: wet overall, dry draws untouched.
        keep_wet = _rain_keep_probability(cos_inc, reflect, t, max_range, dropout, glass, ground)
        keep &= rain_rng.uniform(size=len(idx)) * keep_dry < keep_wet
        reflect = reflect * np.exp(-2.0 * RAIN_EXTINCTION_PER_M * t)

    idx, t_noisy = idx[keep], noisy[keep]
    points = np.zeros((len(dirs), 5), np.float32)
    points[:, 4] = ring
    points[idx, 3] = np.clip(np.round(255.0 * reflect[keep] * cos_inc[keep] * gain[keep]), 0, 255)
    points[idx, :3] = _points_along(origins, dirs, idx, t_noisy) @ reference[:3, :3]
    owner = np.full(len(dirs), -1, np.int32)
    owner[idx] = np.where(on_part[keep], parts.owner[part_hit[keep]] if len(parts) else -1, -1)
    returned = np.zeros(len(dirs), bool)
    returned[idx] = True
    if rain_rng is not None:
        ray_range = np.full(len(dirs), np.inf)
        ray_range[idx] = t_noisy
        origins_lidar, dirs_lidar = origins @ reference[:3, :3], dirs @ reference[:3, :3]
        if spray is not None and len(spray.boxes):
            spray_range = _spray_ranges(spray, reference, origins, dirs, level, spread + 1e-3, start_azimuth,
                                        azimuth_steps, az_margin, el_margin, rain_rng)
            _set_clutter(points, owner, returned, origins_lidar, dirs_lidar,
                         np.flatnonzero(spray_range < ray_range), spray_range, rain_rng)
            ray_range = np.minimum(ray_range, spray_range)
        _add_raindrops(points, owner, returned, origins_lidar, dirs_lidar, ray_range, rain_rng)
    return LidarScan(points=points, owner=owner, returned=returned)
