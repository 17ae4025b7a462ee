"""Camera renderer of the synthetic world: a ray caster with a depth buffer.

Pixel (u, v) looks along K^-1 [u + 0.5, v + 0.5, 1] in the OpenCV camera frame (x right,
y down, z forward); rays are scaled so that the ray parameter is the camera z-depth. The
ground plane z = 0 is intersected by every pixel; each part then casts only the rays of
the pixels inside its projected bounding rectangle, and a depth buffer keeps the nearest
surface. Shading: sun (Lambert, with cast shadows of the objects on every surface) plus a
sky ambient term by normal, a Fresnel reflection of the sky on paint and glass,
procedural detail by material, distance haze, then the camera's style (exposure, white
balance, vignetting, noise) and sRGB encoding.

The generator renders six cameras per keyframe with numpy alone, so the work per pixel is
kept small:

* per-pixel values are float32, and positions are taken relative to the camera, where
  float32 still resolves a tenth of a millimetre at a kilometre;
* a part's rays need no per-pixel rotation: in the part's frame the ray of pixel (u, v)
  is an affine function of (u, v) and the camera is one fixed point, both set up once
  per part (`_PartRays`);
* parts whose rectangle holds many pixels are cast as 2-D blocks on views of the image
  buffers (no gathers, and a part hidden behind nearer scenery is skipped whole); the
  many small ones are cast together as flat (pixel, part) pairs in cache-sized chunks;
* shading and the camera style run over bands of rows small enough for their temporaries
  to stay in cache, with colours and vectors channel-first (3, n);
* surface detail, shadows and reflections are evaluated only where needed: shadow rays
  start from sun-facing points inside the projection of a caster's sun-swept volume, the
  ground shader sees only the pixels where the ground is the nearest surface.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from sianms_cli.synth import shapes
from sianms_cli.synth.appearance import DECAL, LOWER_BODY, SIDE_STRIPE, SOLID, CameraStyle, stack_appearances
from sianms_cli.synth.raycast import T_MIN, slab_interval
from sianms_cli.synth.shapes import Parts

SUN_COLOUR = np.array([1.0, 0.96, 0.9], np.float32)
SUN_IRRADIANCE = 1.5
SKY_AMBIENT = np.array([0.30, 0.33, 0.38], np.float32)
HORIZON = np.array([0.80, 0.86, 0.95], np.float32)
ZENITH = np.array([0.22, 0.38, 0.78], np.float32)
HAZE_DISTANCE = 900.0   # metres for 63 % haze
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

    image (H,W,3) uint8 sRGB, None when only coverage was asked for; owner_map (H,W) int32 object index of the nearest surface
    (-1 for ground, sky and scenery); depth (H,W) float32 z-depth in the camera frame,
    metres (inf for sky); object_pixels (n_objects,) int64 pixels each object covers with
    nothing in front of it; visible_pixels (n_objects,) int64 pixels where it is the
    nearest surface.
    """

    image: np.ndarray | None
    owner_map: np.ndarray
    depth: np.ndarray
    object_pixels: np.ndarray
    visible_pixels: np.ndarray


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
    rows = np.flatnonzero(row_slope + min(0.0, a * (view.width - 1)) < 0.0)
    if height <= 0.0 or len(rows) == 0:
        return depth.reshape(-1)
    rows = slice(rows[0], rows[-1] + 1)
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
        safe = np.where((owner >= 0) & (owner < n_objects), owner, 0)
        self.row = self.shape[safe, 1]
        self.base = self.start[safe] - self.corner[safe, 1] * self.row - self.corner[safe, 0]
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

    def pixels(self) -> np.ndarray:
        """(n_objects,) int64 covered pixels of each object."""
        return np.array([np.count_nonzero(self.bits[s:s + r * c]) for s, (r, c) in zip(self.start, self.shape)],
                        np.int64).reshape(self.n_objects)


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
                n_objects: int) -> np.ndarray:
    """Cast every part into the flat depth (P,) float32 and part (P,) int32 buffers, in
    place (they start with the ground); returns object_pixels (n_objects,) int64.

    Objects come first and are only culled by the ground, so that their coverage can be
    counted; scenery follows front to back, so that a part hidden by nearer ones is
    mostly skipped.
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
    return coverage.pixels()


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


def _sky_radiance(dirs: np.ndarray, sun: np.ndarray) -> np.ndarray:
    """(3,n) float32 linear sky radiance along unit directions dirs (3,n) float32: a
    horizon-to-zenith gradient by elevation, brighter around the sun; below the horizon
    the horizon colour, dimmed."""
    dz = dirs[2]
    t = np.sqrt(np.clip(dz, 0.0, 1.0))
    away = 1 - np.clip(dirs[0] * sun[0] + dirs[1] * sun[1] + dz * sun[2], -1.0, 1.0)
    # cos^n is close to exp(-n (1 - cos)) near the sun, and far cheaper.
    glow = _F32(0.5) * np.exp(_F32(-12.0) * away) + _F32(3.0) * np.exp(_F32(-2000.0) * away)
    col = HORIZON[:, None] + (ZENITH - HORIZON)[:, None] * t + np.array([1.0, 0.9, 0.75], _F32)[:, None] * glow
    return np.where(dz < 0.0, (HORIZON * _F32(0.8))[:, None], col)


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


def _facade(hits: _Hits, wall, glass_colour, seed):
    """Building wall: a window grid on the upper floors and shop windows at street level."""
    (x, y, z), (hx, hy, hz), axis = hits.local, hits.half, hits.axis
    along = np.where(axis == 0, y, x)
    along_half = np.where(axis == 0, hy, hx)
    height = z + hz
    bay = _F32(2.6) + _F32(1.4) * seed
    floor = _F32(3.1) + _F32(0.4) * seed
    fu = _wrap(along + along_half, bay) - bay / 2
    fv = _wrap(height, floor)
    side = axis != 2
    upper = (height > 3.6) & (np.abs(along) < along_half - _F32(0.8)) & (height < 2 * hz - _F32(1.0)) & side
    window = upper & (np.abs(fu) < _F32(0.3) * bay) & (fv > 0.9) & (fv < 2.4)
    shop = (height > 0.5) & (height < 2.9) & (np.abs(along) < along_half - _F32(0.6)) & \
        (np.abs(_wrap(along + along_half, _F32(4.0)) - _F32(2.0)) < 1.85) & side
    glass = window | shop
    sill = upper & (np.abs(fu) < _F32(0.3) * bay + _F32(0.08)) & (fv > 0.78) & (fv <= 0.9)
    colour = np.where(glass, glass_colour, wall)
    return np.where(sill, np.minimum(wall * _F32(1.4), _F32(0.9)), colour), glass


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
    """Albedo (3,Q) float32, glass mask (Q,) and gloss (Q,) float32 of part surface points."""
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

    idx = np.flatnonzero(material == shapes.FACADE)
    if len(idx):
        colour, glass[idx] = _facade(hits.take(idx), _take(albedo, idx), _take(looks.glass, owner[idx]),
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
        white = np.floor((np.take(hits.local[1], idx) + np.take(hits.half[1], idx)) / _F32(0.5)).astype(np.int64) % 2 == 1
        _put(albedo, idx, np.where(white, _F32(0.8), _take(albedo, idx)))

    gloss[glass] = 1.0
    return albedo, glass, gloss


def _part_radiance(table: _PartTable, looks: _Looks, hits: _Hits, n, z_world, view_dir, shadow, sun):
    """(3,Q) float32 linear radiance leaving part surface points towards the camera.

    n (3,Q) float32 global normal; z_world (Q,) float32 height above the ground;
    view_dir(idx) -> (3,n) float32 unit rays of points idx; shadow (Q,) bool; sun (3,)
    float32."""
    albedo, glass, gloss = _surface(table, hits, looks)
    cos_sun = np.maximum(n[0] * sun[0] + n[1] * sun[1] + n[2] * sun[2], 0.0) * ~shadow
    # Contact darkening: surfaces near the ground see less sky (ambient occlusion).
    occlusion = np.clip(_F32(0.45) + _F32(0.55 / 0.7) * z_world, 0.45, 1.0)
    ambient = (_F32(0.75) + _F32(0.25) * n[2]) * occlusion
    radiance = albedo * ((SUN_IRRADIANCE * SUN_COLOUR)[:, None] * cos_sun + SKY_AMBIENT[:, None] * ambient)

    shiny = np.flatnonzero(glass | (gloss > 0))
    if len(shiny):
        ns, vs = _take(n, shiny), view_dir(shiny)
        v_dot_n = (vs * ns).sum(axis=0)
        refl = vs - 2 * v_dot_n * ns
        env = np.where(refl[2] > 0.0, _sky_radiance(refl, sun), _F32(0.1))
        fresnel = _F32(0.04) + _F32(0.96) * (1 - np.abs(v_dot_n)) ** 5
        weight = np.where(glass[shiny], fresnel, gloss[shiny] * fresnel)
        to_sun = refl[0] * sun[0] + refl[1] * sun[1] + refl[2] * sun[2]
        highlight = gloss[shiny] * _F32(6.0) * np.exp(_F32(-300.0) * (1 - np.clip(to_sun, 0.0, 1.0)))
        highlight *= cos_sun[shiny] > 0
        _put(radiance, shiny, _take(radiance, shiny) * (1 - weight) + weight * env + SUN_COLOUR[:, None] * highlight)
    return radiance


def _ground_radiance(ground_shader, xy: np.ndarray, shadow: np.ndarray, sun: np.ndarray) -> np.ndarray:
    """(3,G) float32 linear radiance of ground points xy (G,2) global float64; shadow (G,)."""
    albedo = np.clip(ground_shader(xy), 0.0, 1.0).T.astype(_F32)
    lit = SKY_AMBIENT + (SUN_IRRADIANCE * max(float(sun[2]), 0.0)) * SUN_COLOUR
    return albedo * np.where(shadow, SKY_AMBIENT[:, None], lit[:, None])


def _hazy(radiance: np.ndarray, distance: np.ndarray) -> np.ndarray:
    """Radiance (3,n) seen through distance (n,) metres of haze."""
    clear = np.exp(distance * _F32(-1.0 / HAZE_DISTANCE))
    return HORIZON[:, None] + (radiance - HORIZON[:, None]) * clear


@dataclass(frozen=True)
class _Scene:
    """What shading needs besides the buffers: the parts' table, their owners' looks, the
    ground shader, the view, the unit sun direction (3,) float64, and the shadow casters
    (None when nothing casts a shadow)."""

    part_table: _PartTable
    looks: _Looks
    ground_shader: Callable[[np.ndarray], np.ndarray]
    view: _View
    sun: np.ndarray
    casters: _Casters | None


def _shade(scene: _Scene, depth: np.ndarray, part_buf: np.ndarray, ray_len: np.ndarray, rows: slice) -> np.ndarray:
    """(3,n) float32 linear radiance of the pixels of a band of rows, from the band's
    depth (n,), part_buf (n,) intp and ray_len (n,)."""
    view = scene.view
    sun = scene.sun.astype(_F32)
    rays = _pixel_rays(view, rows)
    radiance = np.empty((3, len(depth)), _F32)
    sky = np.flatnonzero(depth == np.inf)
    _put(radiance, sky, _sky_radiance(_take(rays, sky) / ray_len[sky], sun))

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
        _put(radiance, ground, _hazy(_ground_radiance(scene.ground_shader, xy, shadow[ground], sun),
                                     depth[ground] * ray_len[ground]))
    if len(on_part):
        z_world = part_points[2] + _F32(view.origin[2])
        radiance_parts = _part_radiance(scene.part_table, scene.looks, hits, normal, z_world,
                                        lambda idx: _take(rays, on_part[idx]) / ray_len[on_part[idx]],
                                        shadow[on_part], sun)
        _put(radiance, on_part, _hazy(radiance_parts, depth[on_part] * ray_len[on_part]))
    return radiance


def _apply_style(radiance: np.ndarray, style: CameraStyle, view: _View, rows: slice,
                 rng: np.random.Generator) -> np.ndarray:
    """Linear radiance (3,n) float32 of a band of rows (overwritten) -> its uint8 sRGB
    (rows,W,3): exposure, white balance, vignetting, tone curve, sRGB encoding, sensor
    noise."""
    width, height = view.width, view.height
    gain = EXPOSURE * 2.0 ** style.exposure_stops * np.asarray(style.white_balance, np.float64)
    u = ((np.arange(width) + 0.5 - view.intrinsic[0, 2]) / (width / 2)).astype(_F32)
    v = ((np.arange(rows.start, rows.stop) + 0.5 - view.intrinsic[1, 2]) / (width / 2)).astype(_F32)
    darkening = _F32(style.vignetting / (1.0 + (height / width) ** 2))
    vignette = 1 - darkening * (u[None, :] * u[None, :] + v[:, None] * v[:, None])
    # The tone table's index of each value: exposed radiance times _LUT_STEPS (values past
    # the end of the table are white).
    radiance *= (gain * _LUT_STEPS).astype(_F32)[:, None] * vignette.reshape(-1)
    level = np.take(_TONE_LUT, radiance.astype(np.intp).T, mode="clip")  # pixel-major, as the image
    if style.noise_std > 0:
        noise = np.frombuffer(rng.bytes(level.size), np.uint8).reshape(level.shape)
        level += np.take(_NORMAL_QUANTILES * _F32(255.0 * style.noise_std), noise)
    return np.clip(level, 0.0, 255.0, out=level).astype(np.uint8).reshape(-1, width, 3)


def render_camera(parts: Parts, appearances, ground_shader, intrinsic, cam_to_world, width: int,
                  height: int, style: CameraStyle, sun_direction, n_objects: int,
                  rng: np.random.Generator, shade: bool = True,
                  casts_shadow: np.ndarray | None = None) -> CameraRender:
    """Render one camera image with its owner map and depth buffer.

    parts: every part of the frame, global frame (owner -1 = scenery); appearances:
    sequence of `Appearance`, index = object index (owners >= len give a plain look);
    ground_shader(xy (P,2) global metres) -> (P,3) linear albedo in [0, 1];
    intrinsic (3,3) pinhole K; cam_to_world (4,4) camera (OpenCV axes) to global;
    width, height in pixels; style: the camera's `CameraStyle`; sun_direction (3,) towards
    the sun, global frame (normalised here); n_objects: length of the per-object counts
    (owners outside [0, n_objects) are not counted); rng: draws the sensor noise only;
    shade: False skips shading (image None) when only the coverage counts are needed;
    casts_shadow (M,) bool: the parts that cast shadows (default: the objects', owner >= 0;
    street clutter too where the caller says so).
    """
    view = _make_view(np.asarray(intrinsic, np.float64), np.asarray(cam_to_world, np.float64), width, height)
    sun = np.asarray(sun_direction, np.float64)
    sun = sun / np.linalg.norm(sun)

    ray_len = _ray_lengths(view)
    depth = _ground_depth(view, ray_len)
    part_buf = np.full(width * height, -1, np.int32)
    object_pixels = np.zeros(n_objects, np.int64)
    if len(parts):
        object_pixels = _cast_parts(parts, view, depth, part_buf, n_objects)

    part_buf = part_buf.astype(np.intp)  # numpy gathers by intp indices several times faster
    owner_map = np.take(np.append(parts.owner, np.int32(-1)), part_buf)  # part -1: owner -1
    counted = (owner_map >= 0) & (owner_map < n_objects)
    visible_pixels = np.bincount(owner_map[counted], minlength=n_objects)[:n_objects].astype(np.int64)
    if not shade:
        return CameraRender(image=None, owner_map=owner_map.reshape(height, width),
                            depth=depth.reshape(height, width), object_pixels=object_pixels,
                            visible_pixels=visible_pixels)

    scene = _Scene(_part_table(parts, view), _looks(appearances, parts, n_objects), ground_shader, view, sun,
                   _shadow_casters(parts, view, sun, casts_shadow))
    image = np.empty((height, width, 3), np.uint8)
    band = max(1, _BAND_PIXELS // width)
    for top in range(0, height, band):
        rows = slice(top, min(top + band, height))
        pixels = slice(rows.start * width, rows.stop * width)
        radiance = _shade(scene, depth[pixels], part_buf[pixels], ray_len[pixels], rows)
        image[rows] = _apply_style(radiance, style, view, rows, rng)
    return CameraRender(image=image, owner_map=owner_map.reshape(height, width),
                        depth=depth.reshape(height, width), object_pixels=object_pixels,
                        visible_pixels=visible_pixels)
