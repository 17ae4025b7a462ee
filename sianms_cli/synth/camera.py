"""Camera renderer of the synthetic world: a ray caster with a depth buffer (docs/synthetic_world.md#cameras).

Pixel (u, v) looks along K^-1 [u + 0.5, v + 0.5, 1] in the OpenCV camera frame (x right,
y down, z forward); rays are scaled so that the ray parameter is the camera z-depth. The
ground plane z = 0 is intersected by every pixel; each part then casts only the rays of the
pixels inside its projected bounding rectangle, and a depth buffer keeps the nearest surface.
Shading: sun (Lambert, cast shadows) plus sky ambient, Fresnel reflections of the clouded sky
and the road on paint and glass, procedural facade detail, haze; the scene's `Conditions`
change the light (night lamps and glow, rain's overcast sky and wet road). The frame's radiance
then goes through the lens (night blur, sun glare, rain drops), is metered (auto exposure,
white balance drifting per frame) and encoded by the camera's style.

Per-pixel work is kept small with numpy alone: float32 values with positions relative to the
camera; a part's rays as an affine function of (u, v) in the part's frame (`_PartRays`); large
parts cast as 2-D blocks on views of the image buffers, small ones together as flat (pixel,
part) pairs in cache-sized chunks; shading in bands of rows, channel-first; shadows,
reflections and surface detail evaluated only where needed.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from sianms_cli.synth import shapes
from sianms_cli.synth.appearance import DECAL, LOWER_BODY, SIDE_STRIPE, SOLID, CameraStyle, stack_appearances
from sianms_cli.synth.conditions import Conditions
from sianms_cli.synth.raycast import T_MIN, slab_interval
from sianms_cli.synth.shapes import Parts

SUN_COLOUR = np.array([1.0, 0.96, 0.9], np.float32)
SUN_IRRADIANCE = 1.5
SKY_AMBIENT = np.array([0.30, 0.33, 0.38], np.float32)
HORIZON = np.array([0.80, 0.86, 0.95], np.float32)
ZENITH = np.array([0.22, 0.38, 0.78], np.float32)
HAZE_DISTANCE = 900.0   # metres for 63 % haze
# Night. Night cameras expose some 8-10 stops more than by day; the night radiances below
# are in units of that exposure, so a road under a street lamp lands near mid-grey as in
# real night footage (our own estimate, from nuScenes night images).
NIGHT_AMBIENT = np.array([0.012, 0.013, 0.017], np.float32)   # moon and sky glow, scattered
NIGHT_HORIZON = np.array([0.075, 0.055, 0.038], np.float32)   # city sky glow (sodium/LED, orange)
NIGHT_ZENITH = np.array([0.006, 0.007, 0.012], np.float32)
HEADLIGHT_RADIANCE = np.array([9.0, 8.7, 8.0], np.float32)     # saturates, as lamps do on camera
STREET_LAMP_RADIANCE = np.array([9.0, 7.8, 5.6], np.float32)
STREET_LAMP_COLOUR = np.array([1.0, 0.87, 0.62], np.float32)   # 3000-4000 K LED / high-pressure sodium mix
TAILLIGHT_RADIANCE = 3.0
LAMP_INTENSITY = 110.0  # irradiance x m^2: about 1.7 (a bright road) under an 8 m lamp
LIGHT_RANGE = 70.0      # metres; a lamp's pool is below 1 % of its peak beyond some 40 m
MAX_GLINTS = 24         # nearest emitters mirrored by a wet road
GLINT_FRESNEL = 0.5  # water's Fresnel reflectance at the grazing angles a road is seen at
GLINT_SHARE = 0.15      # a mirror image's core radiance over the emitter's
NIGHT_NOISE_GAIN = 2.5  # sensor noise at night gain over day (our own estimate: +2-3 stops of gain)
# Rain: an overcast sky (no sun, no hard shadows) and a wet road.
RAIN_HORIZON = np.array([0.50, 0.52, 0.55], np.float32)
RAIN_ZENITH = np.array([0.36, 0.38, 0.42], np.float32)
RAIN_AMBIENT = np.array([0.42, 0.44, 0.47], np.float32)
RAIN_HAZE_DISTANCE = 400.0  # metres; moderate rain cuts visibility to 1-2 km
WET_ROAD_MIRROR = 0.8   # share of a wet road that mirrors (film and puddles; our own estimate)
WET_DARKENING = 0.6     # wet asphalt keeps ~60 % of its dry albedo (Lekner & Dorf 1988, Appl. Opt. 27)
WATER_F0 = 0.02         # Fresnel reflectance of water at normal incidence (n = 1.33)
DAY_CLOUD_COVER_MAX = 0.7
WINDOW_GLOW = np.array([0.35, 0.27, 0.17], np.float32)  # a lit room behind a window at night (warm)
GROUND_RANGE = 2000.0   # metres; the ground beyond is drawn as sky
EXPOSURE = 1.0
WHITE_POINT = 3.0       # linear radiance mapped to full white by the tone curve
NEAR = 0.05             # metres; the near clipping plane (z-depth)
SHADOW_OFFSET = 0.01    # metres; shadow rays start this far off the surface along its normal
_CHUNK = 32_768         # (pixel, part) pairs per vectorised step, so temporaries stay in cache
_BLOCK_AREA = 4_096     # parts with more pixels in their rectangle are cast as one 2-D block
_BAND_PIXELS = 24_576   # pixels shaded together: a band of rows whose temporaries stay in cache
_F32 = np.float32

_LUT_STEPS = 4096       # entries of the tone table per unit of exposed radiance


def _tone_table() -> np.ndarray:
    """Tone curve and sRGB encoding of exposed linear radiance x in [0, WHITE_POINT] (above
    it is white): entry i holds the value at the middle of [i, i + 1) / _LUT_STEPS, fine
    enough to be exact to within one 8-bit level, in 8-bit levels plus 0.5 so that
    truncation to uint8 rounds."""
    x = (np.arange(int(WHITE_POINT * _LUT_STEPS) + 1) + 0.5) / _LUT_STEPS
    tone = np.minimum(x * (1.0 + x / WHITE_POINT ** 2) / (1.0 + x), 1.0)
    srgb = np.where(tone <= 0.0031308, 12.92 * tone, 1.055 * np.power(np.maximum(tone, 0.0031308), 1 / 2.4) - 0.055)
    return (255.0 * srgb + 0.5).astype(np.float32)


def _normal_quantiles() -> np.ndarray:
    """(256,) float32 quantiles of the standard normal at (i + 0.5) / 256, rescaled to unit
    variance. Sensor noise is one random byte per sample mapped through them: it looks the
    same as rng.standard_normal and costs a tenth of it."""
    q = np.array([NormalDist().inv_cdf((i + 0.5) / 256) for i in range(256)])
    return (q / np.sqrt(np.mean(q ** 2))).astype(np.float32)


_TONE_LUT = _tone_table()
_NORMAL_QUANTILES = _normal_quantiles()

_CORNER_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)],
                         np.float64)
_BOX_EDGES = np.array([(i, j) for i in range(8) for j in range(i + 1, 8)
                       if (i ^ j).bit_count() == 1])
# The volume a cuboid sweeps towards the ground along the sun: its 8 corners and their 8
# shadows; its outline is made of the box edges, the shadow edges and the sweep lines.
_SWEPT_EDGES = np.concatenate([_BOX_EDGES, _BOX_EDGES + 8, [(i, i + 8) for i in range(8)]])


@dataclass(frozen=True)
class CameraRender:
    """One rendered image.

    image (H,W,3) uint8 sRGB; owner_map (H,W) int32 object index of the nearest surface
    (-1 for ground, sky and scenery); depth (H,W) float32 z-depth in the camera frame,
    metres (inf for sky). `coverage_counts` counts the objects' pixels.
    """

    image: np.ndarray
    owner_map: np.ndarray
    depth: np.ndarray


@dataclass(frozen=True)
class _View:
    """A pinhole camera. Pixel (u, v) (integer column and row) looks from `origin` (3,)
    (global, float64) along the global direction rays @ (u, v, 1), rays (3,3) float64,
    scaled so that the ray parameter is the camera z-depth; the same direction in the
    camera frame is camera_rays @ (u, v, 1); world_to_cam (4,4); side_planes (4,3) unit
    inward normals, camera frame, of the planes through the camera and the image edges."""

    origin: np.ndarray
    rays: np.ndarray
    camera_rays: np.ndarray
    intrinsic: np.ndarray
    world_to_cam: np.ndarray
    width: int
    height: int
    side_planes: np.ndarray


def _make_view(intrinsic, cam_to_world, width: int, height: int) -> _View:
    """The view of a camera with intrinsic (3,3) K and cam_to_world (4,4), float64."""
    to_centre = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.5], [0.0, 0.0, 1.0]])  # index -> pixel centre
    camera_rays = np.linalg.inv(intrinsic) @ to_centre
    w, h = width - 0.5, height - 0.5
    corners = (camera_rays @ np.array([[-0.5, w, w, -0.5], [-0.5, -0.5, h, h], [1.0, 1.0, 1.0, 1.0]])).T
    planes = np.cross(corners, np.roll(corners, -1, axis=0))
    planes *= np.sign(planes @ (camera_rays @ np.array([w / 2, h / 2, 1.0])))[:, None]
    planes /= np.linalg.norm(planes, axis=1, keepdims=True)
    return _View(cam_to_world[:3, 3].copy(), cam_to_world[:3, :3] @ camera_rays, camera_rays, intrinsic,
                 np.linalg.inv(cam_to_world), width, height, planes)


def _box_corners(center: np.ndarray, half_size: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(M,8,3) corners of M yaw-rotated boxes (center (M,3), half_size (M,3), yaw (M,)),
    global frame; corner k has signs `_CORNER_SIGNS[k]`."""
    local = _CORNER_SIGNS[None, :, :] * half_size[:, None, :]
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    x = c * local[..., 0] - s * local[..., 1]
    y = s * local[..., 0] + c * local[..., 1]
    return np.stack([x, y, local[..., 2]], axis=-1) + center[:, None, :]


def project_rects(points_cam: np.ndarray, edges: np.ndarray, intrinsic: np.ndarray,
                  width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel rectangle covering each convex point set's projection.

    points_cam (M,n,3) camera frame; edges (E,2) point pairs whose segments contain the
    outline of each set's convex hull (the parts behind the NEAR plane are clipped along
    them). Returns rects (M,4) int64 (u0, v0, u1, v1), inclusive, clipped to the image,
    and valid (M,) bool (False when the set is entirely behind NEAR or off the image).
    """
    z = points_cam[..., 2]
    front = z > NEAR
    a, b = points_cam[:, edges[:, 0]], points_cam[:, edges[:, 1]]
    za, zb = a[..., 2], b[..., 2]
    cross = (za > NEAR) != (zb > NEAR)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(cross, (NEAR - za) / (zb - za), 0.0)
    q = a + s[..., None] * (b - a)
    pts = np.concatenate([points_cam, q], axis=1)
    ok = np.concatenate([front, cross], axis=1)
    depth = np.where(ok, pts[..., 2], 1.0)
    x = (intrinsic[0, 0] * pts[..., 0] + intrinsic[0, 1] * pts[..., 1]) / depth + intrinsic[0, 2]
    y = intrinsic[1, 1] * pts[..., 1] / depth + intrinsic[1, 2]
    x_lo, x_hi = np.where(ok, x, np.inf).min(axis=1), np.where(ok, x, -np.inf).max(axis=1)
    y_lo, y_hi = np.where(ok, y, np.inf).min(axis=1), np.where(ok, y, -np.inf).max(axis=1)
    valid = front.any(axis=1) & (x_hi >= 0) & (x_lo < width) & (y_hi >= 0) & (y_lo < height)
    big = 1e7
    rects = np.stack([np.clip(np.floor(np.clip(x_lo, -big, big)), 0, width - 1),
                      np.clip(np.floor(np.clip(y_lo, -big, big)), 0, height - 1),
                      np.clip(np.floor(np.clip(x_hi, -big, big)), 0, width - 1),
                      np.clip(np.floor(np.clip(y_hi, -big, big)), 0, height - 1)], axis=1)
    return rects.astype(np.int64), valid


def _camera_points(points: np.ndarray, view: _View) -> np.ndarray:
    """Global points (..., 3) in the camera frame."""
    return points @ view.world_to_cam[:3, :3].T + view.world_to_cam[:3, 3]


def _in_frustum(centres: np.ndarray, radii: np.ndarray, view: _View) -> np.ndarray:
    """(M,) bool: spheres (centres (M,3) global, radii (M,)) that may reach the view
    frustum: in front of the NEAR plane and inside its four side planes. A cheap test
    that spares most parts outside this camera's view the exact projection."""
    c = _camera_points(centres, view)
    return (c[:, 2] + radii > NEAR) & np.all(c @ view.side_planes.T > -radii[:, None], axis=1)


def _pixel_rays(view: _View, rows: slice) -> np.ndarray:
    """(3,n) float32 global ray of every pixel of a band of rows, row-major (camera-frame z
    component 1)."""
    along_u = view.rays[:, :1] * np.arange(view.width) + view.rays[:, 2:]
    along_v = view.rays[:, 1:2] * np.arange(rows.start, rows.stop)
    return (along_v.astype(_F32)[:, :, None] + along_u.astype(_F32)[:, None, :]).reshape(3, -1)


def _ray_lengths(view: _View) -> np.ndarray:
    """(H*W,) float32 length of every pixel's ray (metres per metre of z-depth)."""
    x = (view.camera_rays[0, 0] * np.arange(view.width)[None, :]
         + (view.camera_rays[0, 1] * np.arange(view.height) + view.camera_rays[0, 2])[:, None]).astype(_F32)
    y = (view.camera_rays[1, 1] * np.arange(view.height) + view.camera_rays[1, 2]).astype(_F32)[:, None]
    return np.sqrt(x * x + (y * y + 1)).reshape(-1)


def _ground_depth(view: _View, ray_len: np.ndarray) -> np.ndarray:
    """(H*W,) float32 z-depth at which each pixel's ray meets the ground z = 0, inf where it
    goes up, or meets it beyond GROUND_RANGE."""
    depth = np.full((view.height, view.width), np.inf, _F32)
    height = view.origin[2]
    # The slope (global z of the ray) is a u + b v + c: only the rows where it is negative
    # somewhere, one range of rows, can see the ground.
    a, b, c = view.rays[2]
    row_slope = b * np.arange(view.height) + c
    below = np.flatnonzero(row_slope + min(0.0, a * (view.width - 1)) < 0.0)
    if height <= 0.0 or len(below) == 0:
        return depth.reshape(-1)
    rows = slice(below[0], below[-1] + 1)
    slope = a * np.arange(view.width) + row_slope[rows, None]
    with np.errstate(divide="ignore"):
        # float64 division: near the horizon the slope is tiny. Negative where the ray goes up.
        t = (-height / slope).astype(_F32)
    np.copyto(depth[rows], t, where=(t > 0.0) & (t * ray_len.reshape(depth.shape)[rows] < GROUND_RANGE))
    return depth.reshape(-1)


# --- Casting parts into the depth buffer ---------------------------------------------------

@dataclass(frozen=True)
class _PartRays:
    """The camera's rays in the frames of M parts.

    ray_map (3,3,M) float32: the direction of pixel (u, v)'s ray in part m's frame has
    component k = ray_map[k, 0, m] u + ray_map[k, 1, m] v + ray_map[k, 2, m]; lower, upper
    (3,M) float32: the part's faces minus the camera position, part frame; nearest (M,)
    float32: z-depth of the part's nearest corner, at least NEAR.
    """

    ray_map: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    nearest: np.ndarray

    def entry_depth(self, each, u, v) -> np.ndarray:
        """z-depth (float32, inf for a miss) at which the rays of pixels (u, v) enter parts.

        each(a) gives the value of per-part array a (M,) for every ray: `_per_part` for a
        2-D block of pixels of one part (u (1,w), v (h,1)), `_per_pair` for flat (pixel,
        part) pairs (u, v (n,)).
        """
        d = [each(self.ray_map[k, 0]) * u + (each(self.ray_map[k, 1]) * v + each(self.ray_map[k, 2]))
             for k in range(3)]
        t_near, t_far, _ = slab_interval([each(a) for a in self.lower], [each(a) for a in self.upper], d)
        return np.where((t_near <= t_far) & (t_near > NEAR), t_near, _F32(np.inf))


def _part_rays(parts: Parts, view: _View, nearest: np.ndarray) -> _PartRays:
    """The camera's rays in the frames of all parts; nearest (M,) as in `_PartRays`."""
    c, s = np.cos(parts.yaw), np.sin(parts.yaw)
    to_part = np.zeros((len(parts), 3, 3))  # rotates global vectors into each part's frame
    to_part[:, 0, 0], to_part[:, 0, 1], to_part[:, 1, 0], to_part[:, 1, 1] = c, s, -s, c
    to_part[:, 2, 2] = 1.0
    camera = np.einsum("mij,mj->mi", to_part, view.origin - parts.center)
    return _PartRays(ray_map=np.ascontiguousarray((to_part @ view.rays).transpose(1, 2, 0), _F32),
                     lower=np.ascontiguousarray((-parts.half_size - camera).T, _F32),
                     upper=np.ascontiguousarray((parts.half_size - camera).T, _F32),
                     nearest=nearest.astype(_F32))


def _per_part(m: int):
    """each(a) for a block of pixels of part m: a[m], one scalar for all of them."""
    return lambda a: a[m]


def _per_pair(part: np.ndarray, counts: np.ndarray):
    """each(a) for flat pairs, counts[i] of them for part[i]: a[part[i]] repeated."""
    return lambda a: np.repeat(a[part], counts)


def _pair_chunks(rects: np.ndarray, width: int):
    """Every (pixel, rectangle) pair of rectangles rects (R,4) (u0, v0, u1, v1, inclusive),
    rectangle by rectangle and row by row, in chunks of at most _CHUNK pairs.

    Yields (first, counts, u, v, pix): the chunk holds counts[i] pairs of rectangle
    first + i; u, v (n,) float32 pixel column and row; pix (n,) flat pixel index.
    """
    w = rects[:, 2] - rects[:, 0] + 1
    area = w * (rects[:, 3] - rects[:, 1] + 1)
    end = np.cumsum(area)
    start = end - area
    total = int(end[-1]) if len(end) else 0
    for lo in range(0, total, _CHUNK):
        hi = min(lo + _CHUNK, total)
        first, last = np.searchsorted(end, [lo, hi - 1], side="right")
        sl = slice(first, last + 1)
        counts = np.minimum(end[sl], hi) - np.maximum(start[sl], lo)
        offset = (np.arange(lo, hi) - np.repeat(start[sl], counts)).astype(_F32)
        row_len = np.repeat(w[sl].astype(_F32), counts)
        row = np.floor((offset + _F32(0.5)) / row_len)  # exact: offsets are small integers
        u = offset - row * row_len + np.repeat(rects[sl, 0].astype(_F32), counts)
        v = row + np.repeat(rects[sl, 1].astype(_F32), counts)
        yield first, counts, u, v, (v * _F32(width) + u).astype(np.intp)


def _split_by_area(group: np.ndarray, rects: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices of `group` whose rectangle (rects[group]) is small, and those that are large."""
    r = rects[group]
    large = (r[:, 2] - r[:, 0] + 1) * (r[:, 3] - r[:, 1] + 1) > _BLOCK_AREA
    return group[~large], group[large]


class _Coverage:
    """Pixels each counted object covers with only the ground in front of it.

    One bitmap per object over its rectangle (the union of its parts' rectangles), so that
    a pixel covered by several parts of the object counts once. Built from the owner (M,)
    of every part and the rectangles (M,4) of the parts in `group`.
    """

    def __init__(self, owner: np.ndarray, rects: np.ndarray, group: np.ndarray, n_objects: int):
        self.n_objects = n_objects
        own, r = owner[group], rects[group]
        lo = np.full((n_objects, 2), np.iinfo(np.int64).max)
        hi = np.full((n_objects, 2), -1)
        counted = own < n_objects
        np.minimum.at(lo, own[counted], r[counted, :2])
        np.maximum.at(hi, own[counted], r[counted, 2:])
        self.corner = lo
        self.shape = np.maximum(hi - lo + 1, 0)[:, ::-1]  # (rows, columns); 0 x 0 if absent
        area = self.shape[:, 0] * self.shape[:, 1]
        self.start = np.cumsum(area) - area
        self.bits = np.zeros(int(area.sum()), bool)
        # Flat bit of pixel (u, v) of part m's object: base[m] + v * row[m] + u.
        # Parts of uncounted owners index one extra entry of zeros (there may be no objects at all).
        safe = np.where((owner >= 0) & (owner < n_objects), owner, n_objects)
        self.row = np.append(self.shape[:, 1], 0)[safe]
        corner = np.vstack([self.corner, np.zeros((1, 2), np.int64)])[safe]
        self.base = np.append(self.start, 0)[safe] - corner[:, 1] * self.row - corner[:, 0]
        self.owner = owner

    def counted(self, m: int) -> bool:
        """Whether part m's object is counted."""
        return 0 <= self.owner[m] < self.n_objects

    def block(self, m: int, rect) -> np.ndarray:
        """2-D view of part m's object bitmap over rect (u0, v0, u1, v1)."""
        o = self.owner[m]
        rows, cols = self.shape[o]
        bits = self.bits[self.start[o]:self.start[o] + rows * cols].reshape(rows, cols)
        u0, v0 = self.corner[o]
        return bits[rect[1] - v0:rect[3] - v0 + 1, rect[0] - u0:rect[2] - u0 + 1]

    def mark(self, part: np.ndarray, u: np.ndarray, v: np.ndarray) -> None:
        """Mark pixels (u, v) (float32 (n,)) as covered by the objects of parts (n,)."""
        keep = (self.owner[part] >= 0) & (self.owner[part] < self.n_objects)
        part, u, v = part[keep], u[keep].astype(np.intp), v[keep].astype(np.intp)
        self.bits[self.base[part] + v * self.row[part] + u] = True

    def pixels(self, rows: slice = slice(0, None)) -> np.ndarray:
        """(n_objects,) int64 covered pixels of each object, in the image rows `rows` (all by default)."""
        height, width = self.shape[:, 0], self.shape[:, 1]
        top = self.corner[:, 1]
        stop = height if rows.stop is None else np.clip(rows.stop - top, 0, height)
        first = np.minimum(np.clip(rows.start - top, 0, height), stop)
        covered = np.concatenate([[0], np.cumsum(self.bits, dtype=np.int64)])
        return covered[self.start + stop * width] - covered[self.start + first * width]


def _tiles(rect):
    """Rectangle (u0, v0, u1, v1) split into bands of rows of at most _BAND_PIXELS pixels,
    so that a block's temporaries stay in cache and hidden bands are skipped."""
    u0, v0, u1, v1 = rect
    rows = max(1, _BAND_PIXELS // (u1 - u0 + 1))
    return [(u0, top, u1, min(top + rows - 1, v1)) for top in range(v0, v1 + 1, rows)]


def _cast_block(rays: _PartRays, m: int, rect, depth2d, part2d, cull2d, axes) -> tuple[tuple, np.ndarray] | None:
    """Cast part m's rays over its rectangle (u0, v0, u1, v1) as one 2-D block, in place.

    depth2d, part2d (H,W) buffers; cull2d (H,W): pixels whose value is at most the part's
    nearest z-depth cannot see it (the ground for objects, the depth buffer for scenery),
    and the block shrinks to the rows and columns of the others; axes: float32 (W,) column
    and (H,) row indices. Returns the block's window (slices) and its hits (h,w) bool,
    None when every pixel is culled.
    """
    u0, v0, u1, v1 = rect
    open_ = cull2d[v0:v1 + 1, u0:u1 + 1] > rays.nearest[m]
    rows, cols = np.flatnonzero(open_.any(axis=1)), np.flatnonzero(open_.any(axis=0))
    if len(rows) == 0:
        return None
    window = (slice(v0 + rows[0], v0 + rows[-1] + 1), slice(u0 + cols[0], u0 + cols[-1] + 1))
    open_ = open_[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
    u, v = axes[0][window[1]][None, :], axes[1][window[0]][:, None]
    t = rays.entry_depth(_per_part(m), u, v)
    depth = depth2d[window]
    closer = t < depth
    np.copyto(depth, t, where=closer)
    np.copyto(part2d[window], m, where=closer)
    return window, (t < np.inf) & open_


def _cast_pairs(rays: _PartRays, group: np.ndarray, rects: np.ndarray, width: int, depth, part_buf,
                cull, coverage: _Coverage | None) -> None:
    """Cast the rays of the parts in `group` over their rectangles rects (G,4) as flat
    (pixel, part) pairs, in place on the flat buffers depth, part_buf (P,); cull (P,) as
    in `_cast_block`; coverage: marks the pixels covered by objects, or None."""
    for first, counts, u, v, pix in _pair_chunks(rects, width):
        part = group[first:first + len(counts)]
        t = rays.entry_depth(_per_pair(part, counts), u, v)
        part = np.repeat(part, counts)
        if coverage is not None:
            q = np.flatnonzero((t < np.inf) & (cull[pix] > rays.nearest[part]))
            coverage.mark(part[q], u[q], v[q])
        q = np.flatnonzero(t < depth[pix])
        _keep_nearest(depth, part_buf, pix[q], t[q], part[q])


def _keep_nearest(depth, part_buf, pix, t, part) -> None:
    """Fold hits (pixel pix, z-depth t, part) nearer than depth[pix] into the buffers, in
    place; of hits of one pixel the nearest wins (of equally near ones, the last)."""
    np.minimum.at(depth, pix, t)
    win = depth[pix] == t
    part_buf[pix[win]] = part[win]


def _cast_parts(parts: Parts, view: _View, depth: np.ndarray, part_buf: np.ndarray,
                n_objects: int, scenery_rows: tuple[int, int] | None = None) -> _Coverage:
    """Cast every part into the flat depth (P,) float32 and part (P,) int32 buffers, in
    place (they start with the ground); returns the objects' coverage.

    Objects come first and are only culled by the ground, so that their coverage can be
    counted; scenery follows front to back, so that a part hidden by nearer ones is
    mostly skipped. scenery_rows (first, last): the only rows where scenery is cast (default
    all), for a canvas whose other rows count the objects' coverage alone.
    """
    near = np.flatnonzero(_in_frustum(parts.center, parts.bounding_radius(), view))
    corners_cam = _camera_points(_box_corners(parts.center[near], parts.half_size[near], parts.yaw[near]), view)
    nearest = np.full(len(parts), NEAR)
    nearest[near] = np.maximum(corners_cam[..., 2].min(axis=1), NEAR)
    rects = np.zeros((len(parts), 4), np.int64)
    rects[near], in_view = project_rects(corners_cam, _BOX_EDGES, view.intrinsic, view.width, view.height)
    near = near[in_view]
    rays = _part_rays(parts, view, nearest)
    objects = near[parts.owner[near] >= 0]
    scenery = near[parts.owner[near] < 0]
    scenery = scenery[np.argsort(rays.nearest[scenery], kind="stable")]
    if scenery_rows is not None:
        rects[scenery, 1] = np.maximum(rects[scenery, 1], scenery_rows[0])
        rects[scenery, 3] = np.minimum(rects[scenery, 3], scenery_rows[1])
        scenery = scenery[rects[scenery, 1] <= rects[scenery, 3]]
    coverage = _Coverage(parts.owner, rects, objects, n_objects)
    ground = depth.copy()
    shape = (view.height, view.width)
    axes = (np.arange(view.width, dtype=_F32), np.arange(view.height, dtype=_F32))
    for group, cull, cover in ((objects, ground, coverage), (scenery, depth, None)):
        small, large = _split_by_area(group, rects)
        _cast_pairs(rays, small, rects[small], view.width, depth, part_buf, cull, cover)
        for m in large:
            for tile in _tiles(rects[m]):
                cast = _cast_block(rays, m, tile, depth.reshape(shape), part_buf.reshape(shape),
                                   cull.reshape(shape), axes)
                if cast is not None and cover is not None and cover.counted(m):
                    window, hit = cast
                    rect = (window[1].start, window[0].start, window[1].stop - 1, window[0].stop - 1)
                    cover.block(m, rect)[...] |= hit
    return coverage


# --- Shadows ---------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Casters:
    """Shadow-casting parts, for rays towards the sun from camera-relative points.

    rects (C,4) int64 pixel rectangle (u0, v0, u1, v1, inclusive) covering each caster's
    sun-swept volume (the part and its shadow on the ground); cos, sin (C,) float32 of the
    yaw; centre (3,C) float32 part centre minus the camera position, global axes; half
    (3,C) float32 half size; sun (3,C) float32 sun direction in each part's frame.
    """

    rects: np.ndarray
    cos: np.ndarray
    sin: np.ndarray
    centre: np.ndarray
    half: np.ndarray
    sun: np.ndarray

    def blocks_sun(self, each, x, y, z) -> np.ndarray:
        """Whether a caster blocks the sun from camera-relative points (x, y, z) (float32,
        NaN for none); each(a) as in `_PartRays.entry_depth`."""
        c, s = each(self.cos), each(self.sin)
        rx, ry = x - each(self.centre[0]), y - each(self.centre[1])
        local = (c * rx + s * ry, c * ry - s * rx, z - each(self.centre[2]))
        half = [each(h) for h in self.half]
        t_near, t_far, _ = slab_interval([-h - o for h, o in zip(half, local)], [h - o for h, o in zip(half, local)],
                                         [each(d) for d in self.sun])
        return (t_near <= t_far) & (t_near > T_MIN)

    def shadow(self, start: np.ndarray, rows: slice, width: int) -> np.ndarray:
        """(n,) bool: the shadow ray of each pixel of a band of rows hits a caster.

        start (3,n) float32: camera-relative start point of each pixel's shadow ray, NaN
        where there is none. A pixel is tested against the casters whose rectangle covers it.
        """
        shadow = np.zeros(start.shape[1], bool)
        rects = self.rects.copy()
        rects[:, 1] = np.maximum(rects[:, 1], rows.start) - rows.start
        rects[:, 3] = np.minimum(rects[:, 3], rows.stop - 1) - rows.start
        small, large = _split_by_area(np.flatnonzero(rects[:, 1] <= rects[:, 3]), rects)
        for first, counts, _, _, pix in _pair_chunks(rects[small], width):
            caster = small[first:first + len(counts)]
            hit = self.blocks_sun(_per_pair(caster, counts), *_take(start, pix))
            shadow[pix[hit]] = True
        shape = (rows.stop - rows.start, width)
        for i in large:
            u0, v0, u1, v1 = rects[i]
            window = (slice(v0, v1 + 1), slice(u0, u1 + 1))
            block = [a.reshape(shape)[window] for a in start]
            shadow.reshape(shape)[window] |= self.blocks_sun(_per_part(i), *block)
        return shadow


def _shadow_casters(parts: Parts, view: _View, sun: np.ndarray, casts: np.ndarray | None = None) -> _Casters | None:
    """The parts that may cast a shadow into the image; None when none does.

    casts (M,) bool: the parts allowed to cast one; None for the objects' parts (owner >= 0).
    Buildings cast none: their sun-swept volumes would cost more rays than the whole image.
    """
    if sun[2] <= 1e-3:
        return None
    if casts is None:
        casts = parts.owner >= 0
    # Each swept volume lies within a sphere around the middle of the part's sweep.
    radius = parts.bounding_radius()
    sweep = np.maximum(parts.center[:, 2] + radius, 0.0) / sun[2]
    part = np.flatnonzero(casts & _in_frustum(parts.center - 0.5 * sweep[:, None] * sun,
                                                           radius + 0.5 * sweep, view))
    if len(part) == 0:
        return None
    corners = _box_corners(parts.center[part], parts.half_size[part], parts.yaw[part])
    on_ground = corners - (np.maximum(corners[..., 2:3], 0.0) / sun[2]) * sun
    swept = _camera_points(np.concatenate([corners, on_ground], axis=1), view)
    rects, valid = project_rects(swept, _SWEPT_EDGES, view.intrinsic, view.width, view.height)
    part = part[valid]
    c, s = np.cos(parts.yaw[part]), np.sin(parts.yaw[part])
    sun_local = np.stack([c * sun[0] + s * sun[1], c * sun[1] - s * sun[0], np.full(len(part), sun[2])])
    return _Casters(rects[valid], c.astype(_F32), s.astype(_F32), (parts.center[part] - view.origin).T.astype(_F32),
                    parts.half_size[part].T.astype(_F32), sun_local.astype(_F32))


# --- Shading -------------------------------------------------------------------------------
# Colours and vectors are channel-first, (3, n): numpy broadcasts a (3,) constant over
# (n, 3) rows several times slower, and gathers rows of (n, 3) arrays slower than three
# 1-D gathers.

def _take(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """a[:, idx] of a (k, N) array (idx within [-N, N): -1 is the last column). numpy's
    2-D fancy indexing, or take with the default bounds check, is several times slower."""
    return np.take(a, idx, axis=1, mode="wrap")


def _put(a: np.ndarray, idx: np.ndarray, values: np.ndarray) -> None:
    """a[:, idx] = values for a (k, N) array and values (k, n), one row at a time."""
    for row, value in zip(a, values):
        row[idx] = value


def _wrap(x: np.ndarray, period) -> np.ndarray:
    """x modulo period, in [0, period) up to rounding; numpy's float `%` is some twenty
    times slower."""
    return x - np.floor(x / period) * period


_CLOUD_LATTICE = 64      # lattice cells of the cloud noise's first octave per period
_CLOUD_TEXELS = 8        # texels of the baked cloud texture per first-octave cell
_CLOUD_OCTAVES = ((1, 0.55), (2, 0.28), (4, 0.17))  # (frequency, weight) of the value noise


def _value_noise(lattice: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Smooth value noise in [0, 1] at float64 points (x, y) (n,) of a periodic square
    lattice (L,L) of values, interpolated with a smoothstep."""
    size = lattice.shape[0]
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    i, j = x0.astype(np.intp) % size, y0.astype(np.intp) % size
    i1, j1 = (i + 1) % size, (j + 1) % size
    sx, sy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
    bottom = lattice[j, i] + sx * (lattice[j, i1] - lattice[j, i])
    top = lattice[j1, i] + sx * (lattice[j1, i1] - lattice[j1, i])
    return bottom + sy * (top - bottom)


@functools.lru_cache(maxsize=8)
def _cloud_texture(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(N*N,) float32 periodic cloud noise texture of a sky seed, N = _CLOUD_LATTICE *
    _CLOUD_TEXELS texels a side: the octaves of value noise summed once, so that a pixel
    costs one bilinear look-up (cached: every camera and frame of a scene shares it); and
    its percentiles (101,), so that a cloud cover is a share of the texture."""
    rng = np.random.default_rng(seed)
    n = _CLOUD_LATTICE * _CLOUD_TEXELS
    x = (np.arange(n) + 0.5) / _CLOUD_TEXELS
    xx, yy = np.meshgrid(x, x)
    texture = np.zeros((n, n))
    for frequency, weight in _CLOUD_OCTAVES:
        lattice = rng.random((_CLOUD_LATTICE * frequency, _CLOUD_LATTICE * frequency))
        texture += weight * _value_noise(lattice, xx * frequency, yy * frequency)
    return texture.astype(_F32).reshape(-1), np.percentile(texture, np.arange(101))


def _bilinear(texture: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(n,) float32 bilinear look-up of a periodic square texture (N*N,) float32 at
    float32 texel coordinates (x, y) (n,)."""
    n = _CLOUD_LATTICE * _CLOUD_TEXELS
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    i = x0.astype(np.intp) & (n - 1)
    j = (y0.astype(np.intp) & (n - 1)) * n
    i1 = (i + 1) & (n - 1)
    j1 = (j + n) & (n * n - 1)
    a, b = np.take(texture, j + i), np.take(texture, j + i1)
    c, d = np.take(texture, j1 + i), np.take(texture, j1 + i1)
    bottom = a + fx * (b - a)
    return bottom + fy * (c + fx * (d - c) - bottom)


@dataclass(frozen=True)
class _Sky:
    """The sky of a scene, fixed in the global frame (the same for every camera of it).

    sun (3,) float32 unit direction; horizon, zenith (3,) float32 radiance of the clear sky;
    sun_glow: strength of the brightening around the sun (0 when it is hidden); cover in
    [0, 1]: the share of the sky under cloud; cloud_light, cloud_dark (3,) float32: the
    radiance of thin and thick cloud; texture: the cloud noise (`_cloud_texture`) and
    threshold: its value above which there is cloud; below (3,) float32: what a ray below the
    horizon sees (distant ground).
    """

    sun: np.ndarray
    horizon: np.ndarray
    zenith: np.ndarray
    sun_glow: float
    cover: float
    cloud_light: np.ndarray
    cloud_dark: np.ndarray
    texture: np.ndarray
    threshold: float
    below: np.ndarray

    def radiance(self, dirs: np.ndarray) -> np.ndarray:
        """(3,n) float32 linear radiance along unit directions dirs (3,n) float32: a
        horizon-to-zenith gradient, a glow around the sun, a cloud layer; below the
        horizon `below`."""
        dz = dirs[2]
        t = np.sqrt(np.clip(dz, 0.0, 1.0))
        col = self.horizon[:, None] + (self.zenith - self.horizon)[:, None] * t
        cloud = self.cloud_density(dirs) if self.cover > 0.0 else None
        if self.sun_glow > 0.0:
            sun = self.sun
            away = 1 - np.clip(dirs[0] * sun[0] + dirs[1] * sun[1] + dz * sun[2], -1.0, 1.0)
            # cos^n is close to exp(-n (1 - cos)) near the sun, and far cheaper.
            glow = _F32(0.5) * np.exp(_F32(-12.0) * away) + _F32(3.0) * np.exp(_F32(-2000.0) * away)
            if cloud is not None:
                glow *= 1 - _F32(0.8) * cloud  # cloud veils the sun
            col += np.array([1.0, 0.9, 0.75], _F32)[:, None] * (_F32(self.sun_glow) * glow)
        if cloud is not None:
            # Thick cloud (density near 1) is darker underneath than thin cloud.
            shade = self.cloud_light[:, None] + (self.cloud_dark - self.cloud_light)[:, None] * (cloud * cloud)
            col += (shade - col) * cloud
        return np.where(dz < 0.0, self.below[:, None], col)

    def cloud_density(self, dirs: np.ndarray) -> np.ndarray:
        """(n,) float32 cloud density in [0, 1] along dirs (3,n): noise on a cloud deck
        (coordinates x/z, y/z of the direction), thresholded at the cover. Towards the
        horizon the deck recedes past the noise's detail, so it fades to its mean."""
        lift = np.maximum(dirs[2], _F32(0.0)) + _F32(0.12)
        scale = _F32(2.2 * _CLOUD_TEXELS)  # first-octave cells per unit of the deck's coordinates
        noise = _bilinear(self.texture, dirs[0] / lift * scale, dirs[1] / lift * scale)
        # Cloud where the noise passes the cover's threshold, thickening over 0.1 above it;
        # an overcast sky (cover 1) is thick everywhere, its noise shading it.
        density = np.clip((noise - _F32(self.threshold)) * _F32(10.0) + _F32(self.cover ** 4), 0.0, 1.0)
        fade = np.clip(dirs[2] * _F32(6.0), 0.0, 1.0)
        return _F32(self.cover) + (density - _F32(self.cover)) * fade


@dataclass(frozen=True)
class _Lights:
    """Light sources of a night frame, camera-relative: position (3,L) float32; colour (3,L)
    float32 intensity (irradiance times squared metres at the source's down axis)."""

    position: np.ndarray
    colour: np.ndarray

    def irradiance(self, points: np.ndarray, normal: np.ndarray | None) -> np.ndarray:
        """(3,n) float32 irradiance at camera-relative points (3,n) with unit normals (3,n)
        (None: facing up). Each source is a small downward-facing Lambertian emitter:
        intensity times cos(emission) cos(incidence) over the squared distance; no shadows."""
        d = self.position[:, None, :] - points[:, :, None]  # (3,n,L) towards each light
        d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2] + _F32(0.25)  # +0.25 m^2: no pole at the lamp
        inv = _F32(1.0) / d2
        cos_emit = np.maximum(d[2], 0.0) * np.sqrt(inv)
        cos_in = cos_emit if normal is None else \
            np.maximum(normal[0][:, None] * d[0] + normal[1][:, None] * d[1] + normal[2][:, None] * d[2], 0.0) * \
            np.sqrt(inv)
        return (self.colour @ (cos_emit * cos_in * inv).T).astype(_F32)


@dataclass(frozen=True)
class _Glints:
    """Bright emitters mirrored by a wet road: position (3,E) float32 camera-relative,
    radiance (3,E) float32 of their mirror image's core."""

    position: np.ndarray
    radiance: np.ndarray

    def draw(self, image: np.ndarray, road: np.ndarray, view: _View, fresnel: float) -> None:
        """Add the emitters' mirror images to the road pixels road (H,W) bool of a (3,H,W)
        radiance image, in place: each a vertical streak about 1 degree wide and four
        times as tall, the blur of rough wet asphalt that stretches along the line of sight
        (our own estimate), times the road's Fresnel reflectance fresnel."""
        mirrored = self.position.astype(np.float64)
        mirrored[2] = -2.0 * view.origin[2] - mirrored[2]  # z -> -z about the ground, camera-relative
        cam = view.world_to_cam[:3, :3] @ mirrored
        spread = 0.009 * view.intrinsic[0, 0]  # pixels per standard deviation across the streak
        for (x, y, z), colour in zip(cam.T, self.radiance.T):
            if z <= NEAR:
                continue
            u = view.intrinsic[0, 0] * x / z + view.intrinsic[0, 2]
            v = view.intrinsic[1, 1] * y / z + view.intrinsic[1, 2]
            u0, u1 = max(int(u - 3 * spread), 0), min(int(u + 3 * spread) + 1, view.width)
            v0, v1 = max(int(v - 12 * spread), 0), min(int(v + 12 * spread) + 1, view.height)
            if u0 >= u1 or v0 >= v1:
                continue
            du = (np.arange(u0, u1, dtype=_F32) + _F32(0.5 - u)) / _F32(spread)
            dv = (np.arange(v0, v1, dtype=_F32) + _F32(0.5 - v)) / _F32(4 * spread)
            lobe = np.exp(_F32(-0.5) * (dv[:, None] ** 2 + du[None, :] ** 2)) * road[v0:v1, u0:u1]
            image[:, v0:v1, u0:u1] += (_F32(fresnel) * colour)[:, None, None] * lobe


@dataclass(frozen=True)
class _Lighting:
    """How a frame is lit.

    sky: the `_Sky`; sun (3,) float32 unit direction; sun_light (3,) float32 sun irradiance
    (colour times strength; zero at night and under rain cloud); ambient (3,) float32 sky
    irradiance of an upward surface; haze (3,) float32 colour and haze_distance metres of
    the air; ground_seen (3,) float32 radiance of the road as paint reflects it; wetness in
    [0, 1]: share of the road's mirror reflection; lights: street-light pools (None when
    none); glints: emitters mirrored by a wet road (None when none); night: emitters glow.
    """

    sky: _Sky
    sun: np.ndarray
    sun_light: np.ndarray
    ambient: np.ndarray
    haze: np.ndarray
    haze_distance: float
    ground_seen: np.ndarray
    wetness: float
    lights: _Lights | None
    glints: _Glints | None
    night: bool


def _sky(conditions: Conditions, sun: np.ndarray, sky_seed: int) -> _Sky:
    """The scene's sky: clear with a seeded share of cloud by day, overcast under rain, a
    dark sky with the city's glow near the horizon at night."""
    rng = np.random.default_rng(sky_seed)
    texture, levels = _cloud_texture(sky_seed)
    cover = 1.0 if conditions.rain else float(rng.uniform(0.0, DAY_CLOUD_COVER_MAX))
    threshold = float(np.interp(100.0 * (1.0 - cover), np.arange(101), levels))
    if conditions.night:
        # Clouds at night are lit from below by the city: no brighter than the glow.
        return _Sky(sun.astype(_F32), NIGHT_HORIZON, NIGHT_ZENITH, 0.0, cover, NIGHT_HORIZON * _F32(0.5),
                    NIGHT_HORIZON * _F32(0.3), texture, threshold, NIGHT_AMBIENT * _F32(0.5))
    if conditions.rain:
        return _Sky(sun.astype(_F32), RAIN_HORIZON, RAIN_ZENITH, 0.0, cover, RAIN_HORIZON, RAIN_HORIZON * _F32(0.6),
                    texture, threshold, RAIN_HORIZON * _F32(0.6))
    return _Sky(sun.astype(_F32), HORIZON, ZENITH, 1.0, cover, np.array([0.95, 0.95, 0.97], _F32),
                np.array([0.55, 0.57, 0.62], _F32), texture, threshold, HORIZON * _F32(0.8))


def _emission(parts: Parts) -> np.ndarray:
    """(M,3) float32 radiance each part emits at night: headlights and street lamps
    (HEADLIGHT), tail lights and signal lamps in their own colour (TAILLIGHT), zero for
    the others."""
    emission = np.zeros((len(parts), 3), _F32)
    headlight = parts.material == shapes.HEADLIGHT
    emission[headlight & (parts.owner >= 0)] = HEADLIGHT_RADIANCE
    emission[headlight & (parts.owner < 0)] = STREET_LAMP_RADIANCE
    tail = np.flatnonzero(parts.material == shapes.TAILLIGHT)
    if len(tail) and parts.albedo is not None:
        colour = parts.albedo[tail].astype(_F32)
        emission[tail] = TAILLIGHT_RADIANCE * colour / np.maximum(colour.max(axis=1, keepdims=True), _F32(1e-3))
    return emission


def _night_sources(parts: Parts, view: _View, emission: np.ndarray, wet: bool) -> tuple[_Lights | None, _Glints | None]:
    """Street-light pools (the luminaires within LIGHT_RANGE, lighting from their
    underside) and, on a wet road, the emitters it mirrors (the MAX_GLINTS nearest within
    LIGHT_RANGE)."""
    offset = parts.center - view.origin
    near = np.hypot(offset[:, 0], offset[:, 1]) < LIGHT_RANGE
    lamp = np.flatnonzero(near & (parts.material == shapes.HEADLIGHT) & (parts.owner < 0))
    lights = None
    if len(lamp):
        position = offset[lamp] - np.array([0.0, 0.0, 1.0]) * parts.half_size[lamp, 2:3]
        lights = _Lights(np.ascontiguousarray(position.T, _F32),
                         np.ascontiguousarray((LAMP_INTENSITY * STREET_LAMP_COLOUR)[:, None].repeat(len(lamp), 1)))
    glints = None
    # Only emitters whose mirror image (below the road) may be in view.
    mirrored = parts.center * np.array([1.0, 1.0, -1.0])
    emitter = np.flatnonzero(near & emission.any(axis=1) & _in_frustum(mirrored, np.full(len(parts), 2.0), view))
    if wet and len(emitter):
        emitter = emitter[np.argsort(np.hypot(offset[emitter, 0], offset[emitter, 1]), kind="stable")[:MAX_GLINTS]]
        glints = _Glints(np.ascontiguousarray(offset[emitter].T, _F32),
                         np.ascontiguousarray((GLINT_SHARE * emission[emitter]).T, _F32))
    return lights, glints


def _lighting(conditions: Conditions, sun: np.ndarray, sky_seed: int, parts: Parts, view: _View,
              emission: np.ndarray | None) -> _Lighting:
    """How a frame is lit under its conditions (see `_Lighting`); ``emission`` is a night frame's."""
    sky = _sky(conditions, sun, sky_seed)
    wetness = WET_ROAD_MIRROR if conditions.rain else 0.0
    if conditions.night:
        assert emission is not None, "a night frame's lamps need their emission"
        lights, glints = _night_sources(parts, view, emission, conditions.rain)
        ambient, sun_light, haze = NIGHT_AMBIENT, np.zeros(3, _F32), NIGHT_HORIZON
    else:
        lights = glints = None
        ambient = RAIN_AMBIENT if conditions.rain else SKY_AMBIENT
        sun_light = np.zeros(3, _F32) if conditions.rain else (SUN_IRRADIANCE * SUN_COLOUR).astype(_F32)
        haze = RAIN_HORIZON if conditions.rain else HORIZON
    # The road as the lower body of a car mirrors it: dark asphalt under the frame's light.
    ground_seen = (_F32(0.1) * (ambient + sun_light * _F32(max(float(sun[2]), 0.0)))).astype(_F32)
    return _Lighting(sky, sun.astype(_F32), sun_light, ambient, haze,
                     RAIN_HAZE_DISTANCE if conditions.rain else HAZE_DISTANCE, ground_seen, wetness, lights, glints,
                     conditions.night)


@dataclass(frozen=True)
class _Hits:
    """Q points on part surfaces: part (Q,) index; local (3,Q) float32 coordinates in the
    part's frame (the one along the face normal snapped onto the face); half (3,Q)
    float32 half size; axis (Q,) int8 face normal axis (0 x, 1 y, 2 z)."""

    part: np.ndarray
    local: np.ndarray
    half: np.ndarray
    axis: np.ndarray

    def take(self, idx: np.ndarray) -> _Hits:
        """The points idx (n,)."""
        return _Hits(np.take(self.part, idx), _take(self.local, idx), _take(self.half, idx), np.take(self.axis, idx))


@dataclass(frozen=True)
class _PartTable:
    """Per-part values for shading M parts: centre (3,M) float32 minus the camera position;
    cos, sin (M,) float32 of the yaw; half (3,M) float32 half size; albedo (3,M) float32;
    material (M,); owner (M,) intp (numpy gathers by intp indices several times faster
    than by int32 ones); facade_seed (M,) float32 in [0, 1), varies facades."""

    centre: np.ndarray
    cos: np.ndarray
    sin: np.ndarray
    half: np.ndarray
    albedo: np.ndarray
    material: np.ndarray
    owner: np.ndarray
    facade_seed: np.ndarray


def _part_table(parts: Parts, view: _View) -> _PartTable:
    """The shading table of every part."""
    assert parts.albedo is not None  # Parts.__post_init__ fills it in where not given
    seed = (np.abs(np.sin(parts.center[:, 0] * 12.9898 + parts.center[:, 1] * 78.233)) * 43758.55) % 1.0
    return _PartTable(np.ascontiguousarray((parts.center - view.origin).T, _F32), np.cos(parts.yaw).astype(_F32),
                      np.sin(parts.yaw).astype(_F32), np.ascontiguousarray(parts.half_size.T, _F32),
                      np.ascontiguousarray(parts.albedo.T, _F32), parts.material, parts.owner.astype(np.intp),
                      seed.astype(_F32))


def _part_hits(table: _PartTable, part: np.ndarray, points: np.ndarray) -> tuple[_Hits, np.ndarray]:
    """Surface geometry of camera-relative points (3,Q) float32 on parts part (Q,), and
    the global outward normal (3,Q) float32 of the faces they lie on."""
    c, s = np.take(table.cos, part), np.take(table.sin, part)
    rel = points - _take(table.centre, part)
    local = np.stack([c * rel[0] + s * rel[1], c * rel[1] - s * rel[0], rel[2]])
    half = _take(table.half, part)
    ratio = np.abs(local) / half
    axis = np.where((ratio[0] >= ratio[1]) & (ratio[0] >= ratio[2]), 0,
                    np.where(ratio[1] >= ratio[2], 1, 2)).astype(np.int8)
    on_face = axis == np.arange(3, dtype=np.int8)[:, None]
    sign = np.where(local < 0.0, _F32(-1.0), _F32(1.0))
    local = np.where(on_face, sign * half, local)
    n_local = np.where(on_face, sign, _F32(0.0))
    normal = np.stack([c * n_local[0] - s * n_local[1], s * n_local[0] + c * n_local[1], n_local[2]])
    return _Hits(part, local, half, axis), normal


@dataclass(frozen=True)
class _Looks:
    """Per-owner appearance, channel-first, with a last column (index -1: scenery) of plain
    looks: secondary, glass (3,N+1) float32; pattern (N+1,); pattern_param (4,N+1) float32;
    gloss (N+1,) float32; patterned (N+1,) bool: the pattern draws on paint."""

    secondary: np.ndarray
    glass: np.ndarray
    pattern: np.ndarray
    pattern_param: np.ndarray
    gloss: np.ndarray
    patterned: np.ndarray


def _looks(appearances, parts: Parts, n_objects: int) -> _Looks:
    """The looks of every owner of parts (see `render_camera` for appearances, n_objects)."""
    table = stack_appearances(appearances, max(n_objects, int(parts.owner.max(initial=-1)) + 1))
    plain = {"secondary": np.zeros(3), "glass": np.array([0.03, 0.04, 0.05]), "pattern": SOLID,
             "pattern_param": np.zeros(4), "gloss": 0.3}
    columns = {name: np.ascontiguousarray(np.concatenate([getattr(table, name),
                                                          np.asarray([value], getattr(table, name).dtype)]).T)
               for name, value in plain.items()}
    return _Looks(**columns, patterned=np.isin(columns["pattern"], (SIDE_STRIPE, LOWER_BODY, DECAL)))


def _greenhouse(hits: _Hits, frame_colour, glass_colour):
    """Glazing with a roof, a top rail, pillars between windows and a windscreen frame."""
    (x, y, z), (hx, hy, hz), axis = hits.local, hits.half, hits.axis
    n_win = np.maximum(1, np.round(2 * hx / _F32(1.25)))
    pitch = 2 * hx / n_win
    to_pillar = np.abs(_wrap(x + hx + pitch / 2, pitch) - pitch / 2)
    frame = np.where(axis == 1, (z > hz - _F32(0.07)) | (to_pillar < _F32(0.055)) | (z < -hz + _F32(0.03)),
                     (np.abs(y) > hy - _F32(0.08)) | (z > hz - _F32(0.07)) | (z < -hz + _F32(0.04)))
    frame |= axis == 2
    return np.where(frame, frame_colour, glass_colour), ~frame


def _hash01(a: np.ndarray, b: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """Float32 pseudo-random values in [0, 1) from integer-valued cells (a, b) and seeds
    (same shapes): the usual shader hash, cheap and deterministic."""
    x = np.sin(a * _F32(12.9898) + b * _F32(78.233) + seed * _F32(37.719)) * _F32(43758.547)
    return x - np.floor(x)


# Shopfront sign colours (linear albedo): red, blue, green, yellow, white, black.
_SIGN_COLOURS = np.array([[0.45, 0.04, 0.03], [0.03, 0.10, 0.40], [0.04, 0.25, 0.08], [0.60, 0.45, 0.05],
                          [0.70, 0.70, 0.68], [0.03, 0.03, 0.03]], np.float32).T


def _facade(hits: _Hits, wall, glass_colour, seed):
    """Building wall: a window grid on the upper floors (its bay, floor height and window
    size vary by building), and at street level shop windows, doors, and above them a
    shopfront sign (a coloured band with lettering) or a striped awning.

    Returns the albedo (3,Q), the glass mask (Q,) and the windows lit at night (Q,) bool
    (about a third of them, our own estimate for the evening)."""
    (x, y, z), (hx, hy, hz), axis = hits.local, hits.half, hits.axis
    along = np.where(axis == 0, y, x)
    along_half = np.where(axis == 0, hy, hx)
    height = z + hz
    across = along + along_half
    bay = _F32(2.6) + _F32(1.4) * seed
    floor = _F32(3.1) + _F32(0.4) * seed
    variant = _hash01(seed, seed, seed)
    window_width = (_F32(0.22) + _F32(0.16) * variant) * bay
    window_top = _F32(2.0) + _F32(0.45) * _hash01(seed, variant, seed)
    fu = _wrap(across, bay) - bay / 2
    fv = _wrap(height, floor)
    side = axis != 2
    upper = (height > 3.6) & (np.abs(along) < along_half - _F32(0.8)) & (height < 2 * hz - _F32(1.0)) & side
    window = upper & (np.abs(fu) < window_width) & (fv > 0.9) & (fv < window_top)
    street = (np.abs(along) < along_half - _F32(0.6)) & side
    shop_index = np.floor(across / _F32(4.0))
    su = across - shop_index * _F32(4.0) - _F32(2.0)
    shop_bay = street & (np.abs(su) < 1.85)
    door = shop_bay & (height < 2.2) & (np.abs(su + _F32(1.0)) < 0.5) & (_hash01(shop_index, seed, seed) < 0.4)
    shop = shop_bay & (height > 0.5) & (height < 2.9) & ~door
    glass = window | shop
    sill = upper & (np.abs(fu) < window_width + _F32(0.08)) & (fv > 0.78) & (fv <= 0.9)
    colour = np.where(glass, glass_colour, wall)
    colour = np.where(sill, np.minimum(wall * _F32(1.4), _F32(0.9)), colour)
    colour = np.where(door, wall * _F32(0.3), colour)
    # Over each shop: a sign board or, in some streets' buildings, a striped awning.
    band = street & (height >= 2.95) & (height < 3.5)
    shop_pick = _hash01(shop_index, seed, variant)
    sign_colour = np.take(_SIGN_COLOURS, np.minimum((shop_pick * 6).astype(np.intp), 5), axis=1)
    lettering = (np.abs(height - _F32(3.22)) < 0.1) & (_wrap(across * _F32(3.1), _F32(1.0)) < 0.6) & \
        (np.abs(su) < 1.2)
    awning = variant < 0.35
    stripe = _wrap(across, _F32(0.5)) < 0.25
    band_colour = np.where(awning, np.where(stripe, sign_colour, _F32(0.75)),
                           np.where(lettering, _F32(0.85) - sign_colour * _F32(0.8), sign_colour))
    colour = np.where(band, band_colour, colour)
    lit = window & (_hash01(np.floor(across / bay), np.floor(height / floor), seed) < 0.33)
    return colour, glass, lit


def _paint_pattern(hits: _Hits, base, pattern, param, secondary):
    """Owner patterns on large paint parts: side stripe, contrasting lower body, decal."""
    (x, _, z), (hx, _, hz), axis = hits.local, hits.half, hits.axis
    side = axis == 1
    z_frac = (z + hz) / (2 * hz)
    stripe = (pattern == SIDE_STRIPE) & side & (np.abs(z_frac - param[0]) * 2 * hz < param[1])
    lower = (pattern == LOWER_BODY) & (axis != 2) & (z_frac < param[0])
    dx = x - param[0] * 2 * hx
    dz = z - param[1] * 2 * hz
    in_decal = (np.abs(dx) < param[2]) & (np.abs(dz) < param[3])
    # A ring logo inside the decal keeps decals of one colour family distinguishable.
    ring = np.abs(np.hypot(dx, dz) - _F32(0.6) * param[3]) < _F32(0.18) * param[3]
    decal = (pattern == DECAL) & side & in_decal & ~ring
    return np.where(stripe | lower | decal, secondary, base)


def _surface(table: _PartTable, hits: _Hits, looks: _Looks):
    """Albedo (3,Q) float32, glass mask (Q,), gloss (Q,) float32 and facade windows lit
    at night (Q,) bool of part surface points."""
    material = np.take(table.material, hits.part)
    owner = np.take(table.owner, hits.part)
    albedo = _take(table.albedo, hits.part)
    glass = material == shapes.HEADLIGHT
    gloss = np.zeros(len(material), _F32)

    idx = np.flatnonzero((material == shapes.PAINT) | (material == shapes.PAINT2))
    gloss[idx] = looks.gloss[owner[idx]]
    # Patterns are drawn on the large paint parts of patterned objects only.
    hx, hz = hits.half[0], hits.half[2]
    idx = np.flatnonzero((material == shapes.PAINT) & (owner >= 0) & (hz >= 0.22) & (hx >= 0.4))
    idx = idx[looks.patterned[owner[idx]]]
    if len(idx):
        own = owner[idx]
        _put(albedo, idx, _paint_pattern(hits.take(idx), _take(albedo, idx), looks.pattern[own],
                                         _take(looks.pattern_param, own), _take(looks.secondary, own)))

    idx = np.flatnonzero(material == shapes.GREENHOUSE)
    if len(idx):
        colour, glass[idx] = _greenhouse(hits.take(idx), _take(albedo, idx), _take(looks.glass, owner[idx]))
        _put(albedo, idx, colour)
        gloss[idx] = looks.gloss[owner[idx]]

    lit = np.zeros(len(material), bool)
    idx = np.flatnonzero(material == shapes.FACADE)
    if len(idx):
        colour, glass[idx], lit[idx] = _facade(hits.take(idx), _take(albedo, idx), _take(looks.glass, owner[idx]),
                                               np.take(table.facade_seed, hits.part[idx]))
        _put(albedo, idx, colour)

    idx = np.flatnonzero((material == shapes.TYRE) & (hx > 0.2) & (hits.axis == 1))
    if len(idx):
        tyre = hits.take(idx)
        rho = np.hypot(tyre.local[0], tyre.local[2]) / np.minimum(tyre.half[0], tyre.half[2])
        colour = np.where(rho < 0.55, _F32(0.25), _take(albedo, idx))
        _put(albedo, idx, np.where(rho > 1.0, _F32(0.01), colour))

    idx = np.flatnonzero(material == shapes.BARRIER_STRIPES)
    if len(idx):
        band = np.floor((np.take(hits.local[1], idx) + np.take(hits.half[1], idx)) / _F32(0.5)).astype(np.int64)
        white = band % 2 == 1
        _put(albedo, idx, np.where(white, _F32(0.8), _take(albedo, idx)))

    gloss[glass] = 1.0
    return albedo, glass, gloss, lit


def _part_radiance(scene: _Scene, hits: _Hits, n, points, z_world, view_dir, shadow):
    """(3,Q) float32 linear radiance leaving part surface points towards the camera.

    n (3,Q) float32 global normal; points (3,Q) float32 camera-relative position; z_world
    (Q,) float32 height above the ground; view_dir(idx) -> (3,n) float32 unit rays of
    points idx; shadow (Q,) bool."""
    light = scene.lighting
    sun, sun_light = light.sun, light.sun_light
    albedo, glass, gloss, lit = _surface(scene.part_table, hits, scene.looks)
    cos_sun = np.maximum(n[0] * sun[0] + n[1] * sun[1] + n[2] * sun[2], 0.0) * ~shadow
    # Contact darkening: surfaces near the ground see less sky (ambient occlusion).
    occlusion = np.clip(_F32(0.45) + _F32(0.55 / 0.7) * z_world, 0.45, 1.0)
    ambient = (_F32(0.75) + _F32(0.25) * n[2]) * occlusion
    irradiance = sun_light[:, None] * cos_sun + light.ambient[:, None] * ambient
    if light.lights is not None:
        irradiance += light.lights.irradiance(points, n)
    radiance = albedo * irradiance

    shiny = np.flatnonzero(glass | (gloss > 0))
    if len(shiny):
        ns, vs = _take(n, shiny), view_dir(shiny)
        v_dot_n = (vs * ns).sum(axis=0)
        refl = vs - 2 * v_dot_n * ns
        # Lower panels mirror the road, the others the sky (clouds included).
        env = np.where(refl[2] > 0.0, light.sky.radiance(refl), light.ground_seen[:, None])
        fresnel = _F32(0.04) + _F32(0.96) * (1 - np.abs(v_dot_n)) ** 5
        g = gloss[shiny]
        weight = np.where(glass[shiny], fresnel, g * fresnel)
        # Metallic paints (gloss from 0.6, see the car paints in appearance.py) tint their
        # reflection with the paint colour and spread the highlight; solid paints do not.
        base = _take(albedo, shiny)
        metal = np.clip((g - _F32(0.6)) * _F32(3.0), 0.0, 1.0) * ~glass[shiny]
        tint = 1 + metal * (base / np.maximum(base.max(axis=0), _F32(0.02)) - 1)
        to_sun = refl[0] * sun[0] + refl[1] * sun[1] + refl[2] * sun[2]
        sharpness = _F32(300.0) - _F32(200.0) * metal
        highlight = g * _F32(6.0) * np.exp(-sharpness * (1 - np.clip(to_sun, 0.0, 1.0)))
        highlight *= cos_sun[shiny] > 0
        _put(radiance, shiny, _take(radiance, shiny) * (1 - weight)
             + tint * (weight * env + (sun_light / SUN_IRRADIANCE)[:, None] * highlight))
    if scene.emission is not None:
        glow = np.take(scene.emission, hits.part, axis=1)
        radiance += glow + lit * WINDOW_GLOW[:, None]
    return radiance


def _ground_radiance(scene: _Scene, xy: np.ndarray, points: np.ndarray, dirs: np.ndarray,
                     shadow: np.ndarray) -> np.ndarray:
    """(3,G) float32 linear radiance of ground points xy (G,2) global float64, points
    (3,G) float32 camera-relative, seen along unit rays dirs (3,G); shadow (G,) bool.

    A wet road is darker and mirrors the sky by Fresnel reflectance (water, Schlick's
    approximation) on WET_ROAD_MIRROR of its surface; the night's emitters it mirrors are
    drawn on the whole frame (`_Glints.draw`)."""
    light = scene.lighting
    albedo = np.clip(scene.ground_shader(xy), 0.0, 1.0).T.astype(_F32)
    lit = light.ambient + light.sun_light * _F32(max(float(light.sun[2]), 0.0))
    irradiance = np.where(shadow, light.ambient[:, None], lit[:, None])
    if light.lights is not None:
        irradiance = irradiance + light.lights.irradiance(points, None)
    if light.wetness == 0.0:
        return albedo * irradiance
    radiance = albedo * irradiance * _F32(WET_DARKENING)
    mirror = dirs * np.array([[1.0], [1.0], [-1.0]], _F32)
    fresnel = _F32(light.wetness) * (_F32(WATER_F0) + _F32(1 - WATER_F0) * (1 + dirs[2]) ** 5)
    return radiance + (light.sky.radiance(mirror) - radiance) * fresnel


def _hazy(radiance: np.ndarray, distance: np.ndarray, lighting: _Lighting) -> np.ndarray:
    """Radiance (3,n) seen through distance (n,) metres of the frame's haze."""
    clear = np.exp(distance * _F32(-1.0 / lighting.haze_distance))
    return lighting.haze[:, None] + (radiance - lighting.haze[:, None]) * clear


@dataclass(frozen=True)
class _Scene:
    """What shading needs besides the buffers: the parts' table, their owners' looks, the
    ground shader, the view, the frame's lighting, the shadow casters (None when nothing
    casts a shadow) and the parts' emitted radiance (3,M) float32 (None by day)."""

    part_table: _PartTable
    looks: _Looks
    ground_shader: Callable[[np.ndarray], np.ndarray]
    view: _View
    lighting: _Lighting
    casters: _Casters | None
    emission: np.ndarray | None


def _shade(scene: _Scene, depth: np.ndarray, part_buf: np.ndarray, ray_len: np.ndarray, rows: slice) -> np.ndarray:
    """(3,n) float32 linear radiance of the pixels of a band of rows, from the band's
    depth (n,), part_buf (n,) intp and ray_len (n,)."""
    view = scene.view
    light = scene.lighting
    sun = light.sun
    rays = _pixel_rays(view, rows)
    radiance = np.empty((3, len(depth)), _F32)
    sky = np.flatnonzero(depth == np.inf)
    _put(radiance, sky, light.sky.radiance(_take(rays, sky) / ray_len[sky]))

    ground = np.flatnonzero((part_buf < 0) & (depth < np.inf))
    on_part = np.flatnonzero(part_buf >= 0)
    ground_points = depth[ground] * _take(rays, ground)  # camera-relative
    part_points = depth[on_part] * _take(rays, on_part)
    hits, normal = _part_hits(scene.part_table, part_buf[on_part], part_points)

    shadow = np.zeros(len(depth), bool)
    if scene.casters is not None:
        # Shadow rays start just off the sun-facing surfaces; the others are in their own shade.
        start = np.full((3, len(depth)), np.nan, _F32)
        _put(start, ground, ground_points + np.array([[0.0], [0.0], [SHADOW_OFFSET]], _F32))
        facing = np.flatnonzero(normal[0] * sun[0] + normal[1] * sun[1] + normal[2] * sun[2] > 0)
        _put(start, on_part[facing], _take(part_points, facing) + _F32(SHADOW_OFFSET) * _take(normal, facing))
        shadow = scene.casters.shadow(start, rows, view.width)

    if len(ground):
        xy = view.origin[:2] + ground_points[:2].T.astype(np.float64)
        distance = depth[ground] * ray_len[ground]
        dirs = ground_points / distance
        _put(radiance, ground, _hazy(_ground_radiance(scene, xy, ground_points, dirs, shadow[ground]),
                                     distance, light))
    if len(on_part):
        z_world = part_points[2] + _F32(view.origin[2])
        radiance_parts = _part_radiance(scene, hits, normal, part_points, z_world,
                                        lambda idx: _take(rays, on_part[idx]) / ray_len[on_part[idx]],
                                        shadow[on_part])
        _put(radiance, on_part, _hazy(radiance_parts, depth[on_part] * ray_len[on_part], light))
    return radiance


# --- The lens and the sensor -------------------------------------------------------------

METER_KEY = 0.115  # geometric mean luminance a frame is exposed to: the median of day frames of
#                    this renderer (24 frames of 2 scenes), so day images keep their average exposure
AE_STOPS = (-1.0, 1.0)  # range of the auto exposure in stops (our own estimate; see NIGHT_AMBIENT)
AE_SUBSAMPLE = 7        # the meter reads every 7th pixel
WB_DRIFT = 0.012        # per-frame white-balance drift, standard deviation of each gain
NIGHT_EXPOSURE_S = 0.02  # s; night exposure time (by day ~1 ms: no visible blur)
BLUR_DISTANCE = 10.0    # metres; the distance whose motion sets the night blur length
FLARE_MARGIN = 0.26     # sin of 15 degrees: glare reaches a camera whose view the sun is this near
FLARE_VEIL = np.array([1.0, 0.93, 0.8], np.float32)  # veiling glare radiance next to the sun
# Ghosts of the sun along the line through the image centre: (position along the line from
# the sun (1 = the centre), radius as a share of the width, radiance (3,)); our own estimate
# of a few-element automotive lens.
_GHOSTS = ((1.35, 0.02, (0.10, 0.16, 0.08)), (1.7, 0.045, (0.12, 0.06, 0.14)),
           (2.1, 0.03, (0.16, 0.10, 0.04)), (2.6, 0.07, (0.05, 0.09, 0.12)))
DROPS_MEAN = 5          # lens drops per rainy image (Poisson, plus one)


def motion_blur_length(intrinsic, cam_to_world, ego_velocity, night: bool) -> float:
    """Length in pixels of the horizontal smear of a night exposure: the image motion of
    the scene at BLUR_DISTANCE while the camera moves at ego_velocity (3,) m/s global, over
    NIGHT_EXPOSURE_S; the motion across a side camera's view smears, a forward camera's
    (along its axis) barely does. 0 by day, whose exposures are too short to smear."""
    if not night:
        return 0.0
    across = abs(float(np.asarray(cam_to_world)[:3, 0] @ np.asarray(ego_velocity, np.float64)))
    return float(np.asarray(intrinsic)[0, 0]) * across * NIGHT_EXPOSURE_S / BLUR_DISTANCE


def _auto_gain(radiance: np.ndarray) -> float:
    """The auto exposure's gain for a frame of linear radiance (3,P) float32: METER_KEY over
    the frame's geometric mean luminance (sampled, so a few lamps do not swing it), within
    AE_STOPS."""
    sample = radiance[:, ::AE_SUBSAMPLE]
    luminance = _F32(0.2126) * sample[0] + _F32(0.7152) * sample[1] + _F32(0.0722) * sample[2]
    mean_log = float(np.mean(np.log(np.maximum(luminance, _F32(1e-4)))))
    return float(np.clip(METER_KEY / np.exp(mean_log), 2.0 ** AE_STOPS[0], 2.0 ** AE_STOPS[1]))


def _motion_blur(image: np.ndarray, length: int) -> np.ndarray:
    """Horizontal box blur of length pixels of a (3,H,W) float32 radiance image (edges
    repeat), the smear of a pan during a long exposure."""
    pad_lo, pad_hi = length // 2, length - length // 2
    padded = np.concatenate([np.repeat(image[..., :1], pad_lo + 1, axis=2), image,
                             np.repeat(image[..., -1:], pad_hi, axis=2)], axis=2)
    total = np.cumsum(padded, axis=2, dtype=np.float64)
    width = image.shape[2]
    return ((total[..., length:length + width] - total[..., :width]) / length).astype(_F32)


def _disc(image: np.ndarray, cu: float, cv: float, radius: float):
    """The window (rows, columns slices) of a (3,H,W) image around a disc at (cu, cv) of
    radius pixels, its soft mask (h,w) float32 in [0, 1] and the rows' offsets from the
    centre in radii (h,1) float32; None when off the image."""
    height, width = image.shape[1:]
    u0, u1 = max(int(cu - radius - 1), 0), min(int(cu + radius + 2), width)
    v0, v1 = max(int(cv - radius - 1), 0), min(int(cv + radius + 2), height)
    if u0 >= u1 or v0 >= v1:
        return None
    du = np.arange(u0, u1, dtype=_F32) + _F32(0.5 - cu)
    dv = np.arange(v0, v1, dtype=_F32) + _F32(0.5 - cv)
    r = np.sqrt(du[None, :] ** 2 + dv[:, None] ** 2)
    mask = np.clip((radius - r) / max(0.3 * radius, 1.0), 0.0, 1.0).astype(_F32)
    return (slice(v0, v1), slice(u0, u1)), mask, dv[:, None] / _F32(radius)


def _lens_drops(image: np.ndarray, rng: np.random.Generator) -> None:
    """Rain drops on the lens of a (3,H,W) radiance image, in place: each a blurred,
    brightened disc (a drop is a small lens showing the scene around it out of focus,
    brighter towards its bottom, which images the sky), at positions drawn from rng."""
    width = image.shape[2]
    n = 1 + int(rng.poisson(DROPS_MEAN))
    centre = rng.uniform(0.0, 1.0, (n, 2)) * image.shape[2:0:-1]
    radius = rng.uniform(0.012, 0.04, n) * width
    for (cu, cv), r in zip(centre, radius):
        disc = _disc(image, cu, cv, r)
        if disc is None:
            continue
        window, mask, dv = disc
        around = _disc(image, cu, cv, 2.5 * r)[0]
        blurred = image[:, around[0], around[1]].mean(axis=(1, 2), dtype=np.float64).astype(_F32)
        drop = blurred[:, None, None] * (_F32(1.1) + _F32(0.35) * dv)
        patch = image[:, window[0], window[1]]
        patch += (drop - patch) * (_F32(0.9) * mask)


def _lens_flare(image: np.ndarray, lighting: _Lighting, view: _View) -> None:
    """Glare of the sun on a (3,H,W) radiance image, in place, when the sun is in or
    within FLARE_MARGIN of the view and not behind cloud: a veil around the sun's image
    point and ghosts along the line through the image centre."""
    sky = lighting.sky
    sun_cam = view.world_to_cam[:3, :3] @ lighting.sun.astype(np.float64)
    if sky.sun_glow == 0.0 or lighting.sun[2] <= 0.0 or sun_cam[2] <= 0.0:
        return
    nearness = np.clip(1.0 + float(np.min(view.side_planes @ sun_cam)) / FLARE_MARGIN, 0.0, 1.0)
    clear = 1.0 - 0.9 * float(sky.cloud_density(lighting.sun[:, None])[0]) if sky.cover > 0 else 1.0
    strength = _F32(nearness * clear)
    if strength <= 0.0:
        return
    height, width = image.shape[1:]
    su, sv = (view.intrinsic @ sun_cam)[:2] / sun_cam[2]
    du = np.arange(width, dtype=_F32) + _F32(0.5 - su)
    dv = np.arange(height, dtype=_F32) + _F32(0.5 - sv)
    r = np.sqrt(du[None, :] ** 2 + dv[:, None] ** 2) * _F32(1.0 / width)
    veil = strength * (_F32(0.03) + np.exp(r * _F32(-8.0)))
    image += FLARE_VEIL[:, None, None] * veil
    cu, cv = view.intrinsic[0, 2], view.intrinsic[1, 2]
    for along, size, colour in _GHOSTS:
        disc = _disc(image, su + along * (cu - su), sv + along * (cv - sv), size * width)
        if disc is not None:
            window, mask, _ = disc
            image[:, window[0], window[1]] += np.array(colour, _F32)[:, None, None] * (strength * mask)


def _apply_style(radiance: np.ndarray, gain: np.ndarray, noise_std: float, vignetting: float, view: _View,
                 rows: slice, rng: np.random.Generator) -> np.ndarray:
    """Linear radiance (3,n) float32 of a band of rows (overwritten) -> its uint8 sRGB
    (rows,W,3): gain (3,) (exposure times white balance), vignetting, tone curve, sRGB
    encoding, sensor noise of noise_std."""
    width, height = view.width, view.height
    u = ((np.arange(width) + 0.5 - view.intrinsic[0, 2]) / (width / 2)).astype(_F32)
    v = ((np.arange(rows.start, rows.stop) + 0.5 - view.intrinsic[1, 2]) / (width / 2)).astype(_F32)
    darkening = _F32(vignetting / (1.0 + (height / width) ** 2))
    vignette = 1 - darkening * (u[None, :] * u[None, :] + v[:, None] * v[:, None])
    # The tone table's index of each value: exposed radiance times _LUT_STEPS (values past
    # the end of the table are white).
    radiance *= (np.asarray(gain, np.float64) * _LUT_STEPS).astype(_F32)[:, None] * vignette.reshape(-1)
    level = np.take(_TONE_LUT, radiance.astype(np.intp).T, mode="clip")  # pixel-major, as the image
    if noise_std > 0:
        noise = np.frombuffer(rng.bytes(level.size), np.uint8).reshape(level.shape)
        level += np.take(_NORMAL_QUANTILES * _F32(255.0 * noise_std), noise)
    return np.clip(level, 0.0, 255.0, out=level).astype(np.uint8).reshape(-1, width, 3)


def render_camera(parts: Parts, appearances, ground_shader, intrinsic, cam_to_world, width: int,
                  height: int, style: CameraStyle, sun_direction, n_objects: int,
                  rng: np.random.Generator,
                  casts_shadow: np.ndarray | None = None, conditions: Conditions = Conditions(),
                  motion_blur_px: float = 0.0, sky_seed: int = 0) -> CameraRender:
    """Render one camera image with its owner map and depth buffer.

    parts: every part of the frame, global frame (owner -1 = scenery); appearances:
    sequence of `Appearance`, index = object index (owners >= len give a plain look);
    ground_shader(xy (P,2) global metres) -> (P,3) linear albedo in [0, 1];
    intrinsic (3,3) pinhole K; cam_to_world (4,4) camera (OpenCV axes) to global;
    width, height in pixels; style: the camera's `CameraStyle`; sun_direction (3,) towards
    the sun, global frame (normalised here); n_objects: the number of objects (owners 0 ..
    n_objects - 1); rng: draws the per-frame white-balance drift, the lens drops and the
    sensor noise; casts_shadow (M,) bool: the parts that cast
    shadows (default: the objects', owner >= 0; street clutter too where the caller says
    so); conditions: night (no sun, emitting lamps, street-light pools, more noise) and
    rain (overcast, wet road, drops on the lens); motion_blur_px: length in pixels of the
    horizontal smear of the exposure (night only, where exposures are long); sky_seed:
    seeds the scene's clouds (the same for all its cameras and frames).

    The image is exposed from its own radiance (auto exposure, see `_auto_gain`) on top of
    the style's fixed offset, as a real camera meters each frame.
    """
    view = _make_view(np.asarray(intrinsic, np.float64), np.asarray(cam_to_world, np.float64), width, height)
    sun = np.asarray(sun_direction, np.float64)
    sun = sun / np.linalg.norm(sun)
    depth, part_buf, _, ray_len = _cast_view(parts, view, n_objects=0)  # nothing to count
    owner_map = _owner_map(parts, part_buf)
    image = _render_image(parts, appearances, ground_shader, view, style, sun, n_objects, rng, casts_shadow,
                          conditions, motion_blur_px, sky_seed, depth, part_buf, ray_len)
    return CameraRender(image=image, owner_map=owner_map.reshape(height, width), depth=depth.reshape(height, width))


@dataclass(frozen=True)
class CoverageCounts:
    """Pixel counts (n_objects,) int64 of each object in one camera: visible, where it is the
    nearest surface in the image; in_image, where it covers the image with only the ground in
    front of it; whole, the same over the image extended by `pad_rows` rows above and below, so
    that what the image's top and bottom edges cut off an object counts too."""

    visible: np.ndarray
    in_image: np.ndarray
    whole: np.ndarray


def coverage_counts(parts: Parts, intrinsic, cam_to_world, width: int, height: int, n_objects: int,
                    pad_rows: int = 0) -> CoverageCounts:
    """Cast (no shading) the camera of `render_camera`'s intrinsic, cam_to_world, width and
    height over a canvas `pad_rows` taller at the top and at the bottom, and count each
    object's pixels (owners outside [0, n_objects) are not counted)."""
    padded = np.array(intrinsic, np.float64)
    padded[1, 2] += pad_rows
    view = _make_view(padded, np.asarray(cam_to_world, np.float64), width, height + 2 * pad_rows)
    _, part_buf, coverage, _ = _cast_view(parts, view, n_objects, scenery_rows=(pad_rows, pad_rows + height - 1))
    owner = _owner_map(parts, part_buf[pad_rows * width:(pad_rows + height) * width])
    counted = (owner >= 0) & (owner < n_objects)
    visible = np.bincount(owner[counted], minlength=n_objects)[:n_objects].astype(np.int64)
    return CoverageCounts(visible=visible, in_image=coverage.pixels(slice(pad_rows, pad_rows + height)),
                          whole=coverage.pixels())


def _cast_view(parts: Parts, view: _View, n_objects: int,
               scenery_rows: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray, _Coverage, np.ndarray]:
    """The ground and every part cast into one view (scenery only in scenery_rows, see
    `_cast_parts`): depth (P,) float32, part_buf (P,) intp (-1: ground or sky), the objects'
    coverage and the rays' lengths (P,) float32."""
    ray_len = _ray_lengths(view)
    depth = _ground_depth(view, ray_len)
    part_buf = np.full(view.width * view.height, -1, np.int32)
    if len(parts):
        coverage = _cast_parts(parts, view, depth, part_buf, n_objects, scenery_rows)
    else:
        coverage = _Coverage(parts.owner, np.zeros((0, 4), np.int64), np.zeros(0, np.intp), n_objects)
    return depth, part_buf.astype(np.intp), coverage, ray_len  # numpy gathers by intp several times faster


def _owner_map(parts: Parts, part_buf: np.ndarray) -> np.ndarray:
    """The owner (P,) int32 of each pixel's nearest part (-1 for ground, sky and scenery)."""
    return np.take(np.append(parts.owner, np.int32(-1)), part_buf)  # part -1: owner -1


def _render_image(parts, appearances, ground_shader, view: _View, style: CameraStyle, sun: np.ndarray,
                  n_objects: int, rng: np.random.Generator, casts_shadow, conditions: Conditions,
                  motion_blur_px: float, sky_seed: int, depth, part_buf, ray_len) -> np.ndarray:
    """(H,W,3) uint8 image from the cast buffers (see `render_camera`): shade every band
    into one radiance frame, add the lens effects, meter it, then expose and encode it."""
    width, height = view.width, view.height
    emission = _emission(parts) if conditions.night else None
    lighting = _lighting(conditions, sun, sky_seed, parts, view, emission)
    casters = None if not lighting.sun_light.any() else _shadow_casters(parts, view, sun, casts_shadow)
    scene = _Scene(_part_table(parts, view), _looks(appearances, parts, n_objects), ground_shader, view, lighting,
                   casters, None if emission is None else np.ascontiguousarray(emission.T))
    radiance = np.empty((3, height * width), _F32)
    band = max(1, _BAND_PIXELS // width)
    for top in range(0, height, band):
        pixels = slice(top * width, min(top + band, height) * width)
        radiance[:, pixels] = _shade(scene, depth[pixels], part_buf[pixels], ray_len[pixels],
                                     slice(top, min(top + band, height)))

    frame = radiance.reshape(3, height, width)
    if lighting.glints is not None:
        road = ((part_buf < 0) & (depth < np.inf)).reshape(height, width)
        lighting.glints.draw(frame, road, view, lighting.wetness * GLINT_FRESNEL)
    if conditions.night and motion_blur_px >= 1.0:
        frame[...] = _motion_blur(frame, int(round(motion_blur_px)))
    _lens_flare(frame, lighting, view)
    white_balance = np.asarray(style.white_balance, np.float64) * (1.0 + rng.normal(0.0, WB_DRIFT, 3))
    if conditions.rain:
        _lens_drops(frame, rng)
    gain = EXPOSURE * 2.0 ** style.exposure_stops * _auto_gain(radiance) * white_balance
    noise_std = style.noise_std * (NIGHT_NOISE_GAIN if conditions.night else 1.0)

    image = np.empty((height, width, 3), np.uint8)
    for top in range(0, height, band):
        rows = slice(top, min(top + band, height))
        image[rows] = _apply_style(radiance[:, rows.start * width:rows.stop * width], gain, noise_std,
                                   style.vignetting, view, rows, rng)
    return image
