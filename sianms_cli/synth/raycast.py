"""Ray casting against yaw-rotated cuboid parts and the ground plane z = 0.

The core is the vectorised slab test `slab_interval`, shared with the camera (which sets
up its rays per part itself); `intersect_parts` builds (ray, part) pairs with a
cone-versus-bounding-sphere cull per bundle of consecutive rays, and `reduce_nearest` keeps
the nearest hit per ray.
"""

from __future__ import annotations

import numpy as np

from sianms_cli.synth.shapes import Parts

# Hits closer than this (metres along a unit ray) are ignored, so that rays starting on a
# surface (shadow rays) do not hit the surface they start on.
T_MIN = 1e-4
_MAX_PAIRS = 200_000


def _to_local(origins, dirs, center, yaw):
    """Ray origins and directions in each cuboid's frame, float32 (origins relative to the
    centre are formed in float64 first, so that far-away scenes keep their precision)."""
    dirs = np.asarray(dirs, np.float64)
    origins = np.asarray(origins, np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    rx = origins[..., 0] - center[:, 0]
    ry = origins[..., 1] - center[:, 1]
    rz = origins[..., 2] - center[:, 2]
    f32 = np.float32
    o = ((c * rx + s * ry).astype(f32), (c * ry - s * rx).astype(f32), rz.astype(f32))
    d = ((c * dirs[..., 0] + s * dirs[..., 1]).astype(f32), (c * dirs[..., 1] - s * dirs[..., 0]).astype(f32),
         np.broadcast_to(dirs[..., 2], c.shape).astype(f32))
    return o, d, c, s


def slab_interval(lower, upper, dirs):
    """Slab test: the ray parameters at which rays enter and leave axis-aligned boxes.

    lower, upper: per axis (3 items), each box's lower and upper bound minus the ray
    origin; dirs: per axis, the ray direction; items are float32 arrays or scalars, all
    broadcastable together (the camera passes per-part scalars against 2-D pixel blocks).
    Returns t_near, t_far (the ray is inside the box for t_near <= t <= t_far, so it misses
    when t_near > t_far, or when either is NaN: a ray lying in a face plane) and t_lo, the
    three per-axis entry parameters (the face entered is the axis where t_lo == t_near).
    """
    t_lo, t_near, t_far = [], None, None
    with np.errstate(divide="ignore", invalid="ignore"):
        for lo_k, hi_k, d_k in zip(lower, upper, dirs):
            # A ray parallel to a slab gets +-inf from both planes: inside it, or a miss.
            inv = np.float32(1.0) / d_k
            t1 = lo_k * inv
            t2 = hi_k * inv
            lo, hi = np.minimum(t1, t2), np.maximum(t1, t2)
            t_lo.append(lo)
            t_near = lo if t_near is None else np.maximum(t_near, lo)
            t_far = hi if t_far is None else np.minimum(t_far, hi)
    return t_near, t_far, t_lo


def _slabs(o, d, half_size, t_max):
    """Entry parameter (inf for a miss) and per-axis entry parameters of local rays."""
    half = [half_size[:, k].astype(np.float32) for k in range(3)]
    t_near, t_far, t_lo = slab_interval([-h - o_k for h, o_k in zip(half, o)],
                                        [h - o_k for h, o_k in zip(half, o)], d)
    t_min = np.float32(T_MIN) * np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    hit = (t_near <= t_far) & (t_near > t_min) & (t_near < t_max)
    return np.where(hit, t_near, np.float32(np.inf)), t_lo


def intersect_boxes(origins, dirs, center, half_size, yaw, t_max=np.inf):
    """Slab test of K rays against K cuboids, pair by pair.

    origins, dirs (K,3) or broadcastable, global frame (dirs need not be unit: t is in
    units of |dir|); center (K,3), half_size (K,3), yaw (K,) of the cuboids; t_max scalar
    or (K,). Returns t (K,) float64 (inf for a miss), normal (K,3) unit outward normal of
    the face hit, global frame (zeros for a miss), local_hit (K,3) the hit point in the
    cuboid's frame (zeros for a miss). A ray starting inside a cuboid, or whose entry lies
    before T_MIN * |dir|, misses it; a ray grazing an edge counts as a hit. Computed in
    float32 relative to each cuboid (millimetre precision at a few hundred metres).
    """
    o, d, c, s = _to_local(origins, dirs, center, yaw)
    t32, t_lo = _slabs(o, d, half_size, t_max)
    t = t32.astype(np.float64)
    n = len(t)
    normal = np.zeros((n, 3))
    local_hit = np.zeros((n, 3))
    hit = np.nonzero(np.isfinite(t32))[0]
    if len(hit) == 0:
        return t, normal, local_hit
    th = t32[hit]
    # The face hit is the slab entered last; its coordinate is snapped onto the face.
    axis = np.where(t_lo[0][hit] == th, 0, np.where(t_lo[1][hit] == th, 1, 2))
    n_local = np.zeros((len(hit), 3))
    for k in range(3):
        on = axis == k
        nk = np.where(d[k][hit] > 0, -1.0, 1.0)
        n_local[:, k] = np.where(on, nk, 0.0)
        local_hit[hit, k] = np.where(on, nk * half_size[hit, k], o[k][hit] + th * d[k][hit])
    ch, sh = c[hit], s[hit]
    normal[hit] = np.stack([ch * n_local[:, 0] - sh * n_local[:, 1], sh * n_local[:, 0] + ch * n_local[:, 1],
                            n_local[:, 2]], axis=1)
    return t, normal, local_hit


def intersect_ground(origins, dirs, t_max=np.inf) -> np.ndarray:
    """Ray parameter where rays (R,3) from origins (R,3) or (3,) meet the plane z = 0.

    Only rays going down from above the plane hit; others, and hits beyond t_max
    (scalar or (R,)), give inf.
    """
    origins = np.asarray(origins, np.float64)
    dz = np.asarray(dirs, np.float64)[..., 2]
    oz = np.broadcast_to(origins[..., 2], dz.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -oz / dz
    ok = (dz < 0.0) & (oz > 0.0) & (t < t_max)
    return np.where(ok, t, np.inf)


def reduce_nearest(t_best, part_best, normal_best, local_best, ray, t, part, normal, local) -> None:
    """Fold candidate hits into per-ray nearest-hit buffers, in place.

    t_best (R,) float, part_best (R,) int, normal_best (R,3), local_best (R,3): current
    nearest hits; ray (K,) ray index of each candidate, t (K,) (inf = no hit), part (K,),
    normal (K,3), local (K,3). Of equally near candidates of one ray the last one wins.
    """
    hit = np.isfinite(t)
    ray, t, part, normal, local = ray[hit], t[hit], part[hit], normal[hit], local[hit]
    if len(ray) == 0:
        return
    t_new = t_best.copy()
    np.minimum.at(t_new, ray, t)
    win = (t == t_new[ray]) & (t < t_best[ray])
    r = ray[win]
    part_best[r] = part[win]
    normal_best[r] = normal[win]
    local_best[r] = local[win]
    t_best[:] = t_new


def _bundle_cull(origins, dirs_unit, t_max, parts: Parts, bundle: int) -> tuple[np.ndarray, np.ndarray]:
    """(bundle index, part index) of every pair whose part's bounding sphere the bundle's
    cone of rays can reach within t_max."""
    r = len(origins)
    n_b = -(-r // bundle)
    pad = n_b * bundle - r
    o = np.concatenate([origins, np.repeat(origins[-1:], pad, 0)]).reshape(n_b, bundle, 3)
    d = np.concatenate([dirs_unit, np.repeat(dirs_unit[-1:], pad, 0)]).reshape(n_b, bundle, 3)
    tm = np.concatenate([t_max, np.repeat(t_max[-1:], pad)]).reshape(n_b, bundle).max(axis=1)
    o_mid = o.mean(axis=1)
    spread = np.linalg.norm(o - o_mid[:, None], axis=2).max(axis=1)
    axis = d.sum(axis=1)
    axis_norm = np.linalg.norm(axis, axis=1)
    axis = axis / np.maximum(axis_norm, 1e-12)[:, None]
    cos_half = np.einsum("bkj,bj->bk", d, axis).min(axis=1)
    half = np.where(axis_norm > 1e-9, np.arccos(np.clip(cos_half, -1.0, 1.0)), np.pi)
    radius = parts.bounding_radius()
    rows = max(1, 1_000_000 // max(len(parts), 1))
    out_b, out_m = [], []
    for start in range(0, n_b, rows):
        sl = slice(start, start + rows)
        v = parts.center[None, :, :] - o_mid[sl, None, :]
        dist = np.linalg.norm(v, axis=2)
        rad = radius[None, :] + spread[sl, None]
        cos_v = np.einsum("bmj,bj->bm", v, axis[sl]) / np.maximum(dist, 1e-12)
        ang = np.arccos(np.clip(cos_v, -1.0, 1.0))
        reach_ang = np.arcsin(np.clip(rad / np.maximum(dist, 1e-12), 0.0, 1.0))
        ok = ((dist <= rad) | (ang - half[sl, None] <= reach_ang)) & (dist - rad <= tm[sl, None])
        b, m = np.nonzero(ok)
        out_b.append(b + start)
        out_m.append(m)
    return np.concatenate(out_b), np.concatenate(out_m)


def intersect_parts(origins, dirs, parts: Parts, t_max=np.inf, bundle: int = 256):
    """Nearest hit of each ray among all parts.

    origins (R,3) or (3,), dirs (R,3) global frame (t is in units of |dir|); parts in the
    global frame; t_max scalar or (R,). Consecutive rays are grouped in bundles of
    `bundle`; a part is tested only against the bundles whose cone can reach its bounding
    sphere, and pairs are processed in slices of bounded size (memory stays below ~100 MB
    whatever R and M). Keep coherent rays adjacent (image rows, LiDAR firing order) for
    good culling. Returns t (R,) float64 (inf = no hit), part (R,) int64 (-1 = no hit),
    normal (R,3) global unit normal, local_hit (R,3) hit point in the part's frame.
    """
    dirs = np.asarray(dirs, np.float64).reshape(-1, 3)
    r = len(dirs)
    origins = np.broadcast_to(np.asarray(origins, np.float64), (r, 3))
    t_max = np.broadcast_to(np.asarray(t_max, np.float64), (r,))
    t_best = np.full(r, np.inf)
    part_best = np.full(r, -1, np.int64)
    normal_best = np.zeros((r, 3))
    local_best = np.zeros((r, 3))
    if r == 0 or len(parts) == 0:
        return t_best, part_best, normal_best, local_best
    norm = np.linalg.norm(dirs, axis=1)
    dirs_unit = dirs / np.maximum(norm, 1e-300)[:, None]
    b_idx, m_idx = _bundle_cull(origins, dirs_unit, t_max * norm, parts, bundle)
    step = max(1, _MAX_PAIRS // bundle)
    lane = np.arange(bundle)
    for start in range(0, len(b_idx), step):
        b, m = b_idx[start:start + step], m_idx[start:start + step]
        ray = (b[:, None] * bundle + lane[None, :]).ravel()
        part = np.repeat(m, bundle)
        keep = ray < r
        ray, part = ray[keep], part[keep]
        t, normal, local = intersect_boxes(origins[ray], dirs[ray], parts.center[part],
                                           parts.half_size[part], parts.yaw[part], t_max[ray])
        reduce_nearest(t_best, part_best, normal_best, local_best, ray, t, part, normal, local)
    return t_best, part_best, normal_best, local_best
