"""Solid shapes of the synthetic world as sets of yaw-rotated cuboid parts: the parts,
their materials, the builder every shape uses, and the shapes of static objects and
street clutter (vehicles.py and people.py hold the road users; objects.py every kind).

Every object is built in its local frame (annotation box centre at the origin, x forward
along the length l, y left along the width w, z up along the height h) from a few cuboid
parts, then placed in the global frame. The union of an object's parts fills its
w x l x h annotation box exactly, as nuScenes cuboids are drawn tight to the LiDAR points.

Each part carries a material (an index into `MATERIALS`) and a linear albedo baked from
the object's appearance; the renderer adds the procedural detail (window grids, pillars,
stripes, decals) from the material and the hit position in the part's frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sianms_cli.synth.appearance import Appearance

MATERIALS = (
    "paint",        # owner's body colour; carries the owner's pattern (stripe, decal, lower body)
    "paint2",       # owner's secondary colour (cargo box, rider helmet, backpack)
    "greenhouse",   # glazed volume: glass panes with pillars and a roof in the part's albedo
    "tyre",
    "headlight",
    "taillight",
    "plate",
    "trim",         # dark plastic and rubber: bumpers, seats, handlebars, chassis
    "metal",        # bare metal: engines, forks, poles
    "cloth",
    "skin",
    "hair",
    "cone",         # traffic-cone orange
    "reflector",    # retro-reflective white band
    "concrete",
    "barrier_stripes",  # red and white plastic barrier, stripes along the part's y
    "facade",       # building wall with a window grid
)
PAINT, PAINT2, GREENHOUSE, TYRE, HEADLIGHT, TAILLIGHT, PLATE, TRIM, METAL, CLOTH, SKIN, \
    HAIR, CONE, REFLECTOR, CONCRETE, BARRIER_STRIPES, FACADE = range(len(MATERIALS))

# Linear albedo of each material when no appearance colour is baked in.
MATERIAL_ALBEDO = np.array([
    [0.50, 0.50, 0.50],  # paint
    [0.30, 0.30, 0.30],  # paint2
    [0.05, 0.05, 0.05],  # greenhouse frame
    [0.025, 0.025, 0.025],  # tyre
    [0.85, 0.85, 0.80],  # headlight
    [0.60, 0.03, 0.02],  # taillight
    [0.80, 0.80, 0.75],  # plate
    [0.035, 0.035, 0.04],  # trim
    [0.30, 0.30, 0.32],  # metal
    [0.20, 0.20, 0.20],  # cloth
    [0.45, 0.30, 0.22],  # skin
    [0.04, 0.03, 0.02],  # hair
    [0.80, 0.20, 0.02],  # cone
    [0.85, 0.85, 0.85],  # reflector
    [0.40, 0.39, 0.36],  # concrete
    [0.55, 0.04, 0.03],  # barrier stripes (red; the others are white)
    [0.40, 0.36, 0.30],  # facade
], dtype=np.float32)

@dataclass(frozen=True)
class Parts:
    """M cuboid parts, aligned arrays.

    center (M,3) float64 metres, in the frame of the caller (object-local or global);
    half_size (M,3) half extents along the part's own x (forward), y (left), z (up);
    yaw (M,) radians about +z; owner (M,) int32 object index, -1 for static scenery;
    material (M,) int16 index into `MATERIALS`; albedo (M,3) float32 linear RGB in [0, 1],
    filled from `MATERIAL_ALBEDO` when not given.
    """

    center: np.ndarray
    half_size: np.ndarray
    yaw: np.ndarray
    owner: np.ndarray
    material: np.ndarray
    albedo: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", np.asarray(self.center, np.float64).reshape(-1, 3))
        object.__setattr__(self, "half_size", np.asarray(self.half_size, np.float64).reshape(-1, 3))
        object.__setattr__(self, "yaw", np.asarray(self.yaw, np.float64).reshape(-1))
        object.__setattr__(self, "owner", np.asarray(self.owner, np.int32).reshape(-1))
        object.__setattr__(self, "material", np.asarray(self.material, np.int16).reshape(-1))
        if self.albedo is None:
            albedo = MATERIAL_ALBEDO[self.material]
        else:
            albedo = np.asarray(self.albedo, np.float32).reshape(-1, 3)
        object.__setattr__(self, "albedo", albedo)
        m = len(self.center)
        for name in ("half_size", "yaw", "owner", "material", "albedo"):
            if len(getattr(self, name)) != m:
                raise ValueError(f"Parts.{name} has {len(getattr(self, name))} rows, center has {m}")

    def __len__(self) -> int:
        return len(self.center)

    def bounding_radius(self) -> np.ndarray:
        """(M,) radius of each part's bounding sphere, centred on `center`."""
        return np.linalg.norm(self.half_size, axis=1)


def empty_parts() -> Parts:
    """A set of zero parts."""
    return Parts(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int32),
                 np.zeros(0, np.int16), np.zeros((0, 3), np.float32))


def concat_parts(parts_list: list[Parts]) -> Parts:
    """Concatenate part sets in order; an empty list gives zero parts."""
    if not parts_list:
        return empty_parts()
    return Parts(
        np.concatenate([p.center for p in parts_list]),
        np.concatenate([p.half_size for p in parts_list]),
        np.concatenate([p.yaw for p in parts_list]),
        np.concatenate([p.owner for p in parts_list]),
        np.concatenate([p.material for p in parts_list]),
        np.concatenate([p.albedo for p in parts_list]),
    )


def place_parts(parts: Parts, center: np.ndarray, yaw: float, owner: int) -> Parts:
    """Move object-local parts to the global frame.

    parts: in the object frame; center (3,) global position of the object's box centre
    (metres); yaw radians about +z; owner: object index written into every part (-1 for
    scenery). Returns a new `Parts` in the global frame.
    """
    assert parts.albedo is not None  # __post_init__ fills it in where not given
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return Parts(
        parts.center @ rot.T + np.asarray(center, np.float64),
        parts.half_size.copy(),
        parts.yaw + yaw,
        np.full(len(parts), owner, np.int32),
        parts.material.copy(),
        parts.albedo.copy(),
    )


class Builder:
    """Collects axis-aligned parts given by their min/max corners, then fits them to a box."""

    def __init__(self) -> None:
        self._lo: list[tuple[float, float, float]] = []
        self._hi: list[tuple[float, float, float]] = []
        self._material: list[int] = []
        self._albedo: list[np.ndarray] = []

    def add(self, lo, hi, material: int, albedo=None) -> None:
        self._lo.append(tuple(lo))
        self._hi.append(tuple(hi))
        self._material.append(material)
        self._albedo.append(MATERIAL_ALBEDO[material] if albedo is None
                            else np.asarray(albedo, np.float32))

    def add_center(self, center, half, material: int, albedo=None) -> None:
        c, h = np.asarray(center, float), np.asarray(half, float)
        self.add(c - h, c + h, material, albedo)

    def fitted(self, size_wlh: np.ndarray) -> Parts:
        """Parts scaled per axis so that their union's bounding box is exactly the
        annotation box (l along x, w along y, h along z, centred at the origin)."""
        lo, hi = np.array(self._lo), np.array(self._hi)
        w, l, h = (float(v) for v in size_wlh)
        target = np.array([l, w, h]) / 2.0
        union_lo, union_hi = lo.min(axis=0), hi.max(axis=0)
        scale = 2.0 * target / (union_hi - union_lo)
        lo = (lo - union_lo) * scale - target
        hi = (hi - union_lo) * scale - target
        m = len(lo)
        return Parts((lo + hi) / 2.0, (hi - lo) / 2.0, np.zeros(m), np.zeros(m, np.int32),
                     np.array(self._material, np.int16), np.array(self._albedo, np.float32))


def ring(b: Builder, cx: float, cz: float, radius: float, y_half: float, thickness: float,
          material: int, segments: int = 12) -> None:
    """A wheel rim seen from the side, as `segments` small boxes along a circle in x-z."""
    ang = (np.arange(segments) + 0.5) * 2.0 * np.pi / segments
    seg = np.pi * radius / segments
    for a in ang:
        x, z = cx + (radius - thickness) * np.cos(a), cz + (radius - thickness) * np.sin(a)
        hx = abs(np.sin(a)) * seg + thickness
        hz = abs(np.cos(a)) * seg + thickness
        b.add_center((x, 0.0, z), (hx, y_half, hz), material)


def _barrier(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    z0 = -h / 2
    if app.variant % 2 == 0:
        b.add((-l / 2, -w / 2, z0), (l / 2, w / 2, z0 + 0.3 * h), CONCRETE, app.base)
        b.add((-0.22 * l, -w / 2, z0 + 0.3 * h), (0.22 * l, w / 2, h / 2), CONCRETE, app.base)
    else:
        b.add((-l / 2, -w / 2, z0), (l / 2, -w / 2 + 0.25, z0 + 0.12), TRIM)
        b.add((-l / 2, w / 2 - 0.25, z0), (l / 2, w / 2, z0 + 0.12), TRIM)
        b.add((-0.1 * l, -w / 2, z0 + 0.12), (0.1 * l, w / 2, h / 2), BARRIER_STRIPES, app.base)


def _cone(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    z0 = -h / 2
    b.add((-l / 2, -w / 2, z0), (l / 2, w / 2, z0 + 0.05), TRIM)
    tiers = 5
    for i in range(tiers):
        frac = 1.0 - i / tiers
        half = 0.08 + 0.24 * frac
        material = REFLECTOR if i in (2, 3) else CONE
        b.add((-half * l, -half * w, z0 + 0.05 + (h - 0.05) * i / tiers),
              (half * l, half * w, z0 + 0.05 + (h - 0.05) * (i + 1) / tiers), material)


def _building(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    b.add((-l / 2, -w / 2, -h / 2), (l / 2, w / 2, h / 2 - 0.4), FACADE, app.base)
    b.add((-l / 2, -w / 2, h / 2 - 0.4), (l / 2, w / 2, h / 2), CONCRETE, app.secondary)


# --- Street clutter: unannotated scenery (see clutter.py for where it stands) -----------------
# Foliage and bark reuse CLOTH (matte, no pattern) with the appearance's colours baked in.

CROWN_BASE = 2.6
"""Height (m) of a street tree's lowest branches: pruned above pedestrians (and the
2.4 m of the tallest annotated walkers' boxes)."""
OVERHEAD_CLEARANCE = 4.8
"""Height (m) above which a clutter part may reach over the carriageway (crowns, lamp
arms, cross-arms): above the tallest vehicle box (mean + 2 std truck height, 4.5 m) and
within the 4.3-5.0 m vertical clearance that road design guides ask for."""
CROWN_KERB_SIDE = 0.5
"""How far (m) a tree's crown below `OVERHEAD_CLEARANCE` reaches from the trunk towards
the road: crowns are lifted over the carriageway, as arborists prune street trees."""
STREET_LIGHT_POLE_INSET = 0.13
"""Distance (m) from a street light's +y box face to its pole's axis (base plinth half
width). The pole stands at y = w/2 - inset and its arm reaches towards -y, over the road;
every other clutter kind stands at its box centre."""


def _tree(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    """Trunk at the box centre; crown in three tiers, the lowest lifted on the -y (road) side."""
    z0 = -h / 2
    trunk = float(np.clip(0.03 * w, 0.1, 0.18))
    lift = z0 + OVERHEAD_CLEARANCE + 0.1
    b.add_center((0.0, 0.0, z0 + (lift - z0) / 2), (trunk, trunk, (lift - z0) / 2), CLOTH, app.secondary)
    b.add((-0.4 * l, -CROWN_KERB_SIDE, z0 + CROWN_BASE), (0.4 * l, 0.4 * w, lift), CLOTH, app.base)
    b.add((-l / 2, -w / 2, lift), (l / 2, w / 2, h / 2 - 0.3 * (h / 2 - lift)), CLOTH, app.base)
    b.add((-0.3 * l, -0.3 * w, h / 2 - 0.3 * (h / 2 - lift)), (0.3 * l, 0.3 * w, h / 2), CLOTH,
          app.base * np.float32(0.8))


def _hedge(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    b.add((-l / 2, -w / 2, -h / 2), (l / 2, w / 2, h / 2 - 0.15), CLOTH, app.base)
    b.add((-l / 2 + 0.1, -w / 2 + 0.08, h / 2 - 0.15), (l / 2 - 0.1, w / 2 - 0.08, h / 2), CLOTH,
          app.base * np.float32(1.15))


def _fence(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    """One panel: a post at each end, two rails and bars about every 0.4 m."""
    z0 = -h / 2
    post = 0.05
    for x in (-l / 2 + post, l / 2 - post):
        b.add_center((x, 0.0, 0.0), (post, w / 2, h / 2), METAL, app.base)
    for z in (z0 + 0.12, h / 2 - 0.06):
        b.add_center((0.0, 0.0, z), (l / 2 - 2 * post, 0.015, 0.02), METAL, app.base)
    bars = max(1, int(round((l - 4 * post) / 0.4)))
    for x in (np.arange(bars) + 0.5) / bars * (l - 4 * post) - (l / 2 - 2 * post):
        b.add_center((x, 0.0, 0.0), (0.012, 0.012, h / 2 - 0.02), METAL, app.base)


def _street_light(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    """Pole at the +y end, an arm at the top towards -y (the road), a luminaire at its end."""
    z0, r = -h / 2, STREET_LIGHT_POLE_INSET - 0.04
    pole_y = w / 2 - STREET_LIGHT_POLE_INSET
    b.add_center((0.0, pole_y, 0.0), (r, r, h / 2), METAL, app.base)
    b.add((-0.04, -w / 2 + 0.3, h / 2 - 0.3), (0.04, pole_y, h / 2 - 0.2), METAL, app.base)
    b.add((-l / 2, -w / 2, h / 2 - 0.35), (l / 2, -w / 2 + 0.6, h / 2 - 0.15), TRIM)
    b.add((-l / 2 + 0.04, -w / 2 + 0.04, h / 2 - 0.38), (l / 2 - 0.04, -w / 2 + 0.56, h / 2 - 0.35),
          HEADLIGHT)
    b.add_center((0.0, pole_y, z0 + 0.4), (r + 0.04, r + 0.04, 0.4), METAL, app.base)


def _utility_pole(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    """A wooden or concrete pole with a cross-arm along y at the top."""
    r = 0.5 * l
    b.add_center((0.0, 0.0, 0.0), (r, r, h / 2), CONCRETE, app.base)
    b.add((-0.05, -w / 2, h / 2 - 0.9), (0.05, w / 2, h / 2 - 0.78), TRIM)


def _sign(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    """A post with a retro-reflective plate facing +x, its bottom 2.1 m up."""
    z0 = -h / 2
    b.add_center((0.0, 0.0, 0.0), (0.03, 0.03, h / 2), METAL)
    b.add((0.03, -w / 2, z0 + 2.1), (l / 2, w / 2, h / 2), REFLECTOR, app.base)
    b.add((-l / 2, -w / 2 + 0.02, z0 + 2.12), (-0.03, w / 2 - 0.02, h / 2 - 0.02), METAL)


def _traffic_light(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    """A pedestal signal: a pole at the box centre carrying a head facing +x at its top,
    the head's bottom 2.5 m up (signal housings clear the pavement by at least 2.4 m)."""
    head_lo = h / 2 - 1.0
    b.add((-0.07, -0.07, -h / 2), (0.07, 0.07, head_lo + 0.1), METAL, app.base)
    b.add((-0.12, -w / 2 + 0.03, head_lo), (0.12, w / 2 - 0.03, h / 2), TRIM)
    for k, colour in enumerate(((0.02, 0.45, 0.12), (0.55, 0.30, 0.02), (0.60, 0.03, 0.02))):
        b.add_center((0.13, 0.0, head_lo + 0.17 + 0.33 * k), (0.01, 0.1, 0.1), TAILLIGHT, colour)
    b.add((-l / 2, -w / 2, head_lo + 0.05), (-0.12, w / 2, h / 2 - 0.05), TRIM)
    b.add((0.14, -w / 2 + 0.03, h / 2 - 0.04), (l / 2, w / 2 - 0.03, h / 2), TRIM)


def _hydrant(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    z0 = -h / 2
    b.add((-l / 2, -l / 2, z0), (l / 2, l / 2, z0 + 0.08), PAINT, app.base)
    b.add((-0.35 * l, -0.35 * l, z0 + 0.08), (0.35 * l, 0.35 * l, h / 2 - 0.12), PAINT, app.base)
    b.add((-0.25 * l, -0.25 * l, h / 2 - 0.12), (0.25 * l, 0.25 * l, h / 2), PAINT2, app.secondary)
    b.add_center((0.0, 0.0, z0 + 0.55 * h), (0.06, w / 2, 0.06), PAINT2, app.secondary)


def _bin(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    b.add((-l / 2 + 0.03, -w / 2 + 0.03, -h / 2), (l / 2 - 0.03, w / 2 - 0.03, h / 2 - 0.08), PAINT,
          app.base)
    b.add((-l / 2, -w / 2, h / 2 - 0.08), (l / 2, w / 2, h / 2), TRIM)


def _bollard(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    b.add((-l / 2, -w / 2, -h / 2), (l / 2, w / 2, h / 2 - 0.2), METAL, app.base)
    b.add((-l / 2, -w / 2, h / 2 - 0.2), (l / 2, w / 2, h / 2 - 0.12), REFLECTOR)
    b.add((-0.8 * l / 2, -0.8 * w / 2, h / 2 - 0.12), (0.8 * l / 2, 0.8 * w / 2, h / 2), METAL, app.base)


BUILDERS = {
    "barrier": _barrier,
    "traffic_cone": _cone,
    "building": _building,
    "tree": _tree,
    "hedge": _hedge,
    "fence": _fence,
    "street_light": _street_light,
    "utility_pole": _utility_pole,
    "sign": _sign,
    "traffic_light": _traffic_light,
    "hydrant": _hydrant,
    "bin": _bin,
    "bollard": _bollard,
}
"""Builders of static objects and street clutter: kind -> f(builder, w, l, h, appearance)."""
