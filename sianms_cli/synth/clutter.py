"""Street clutter: unannotated furniture and vegetation, in the images and the LiDAR.

Real frustums are full of background: trees, poles, signs and bins stand between the camera
and the objects and put points around them. `clutter_parts` places them along a street as
owner -1 scenery, posed in the global frame; nothing here is annotated. The densities and the
design guides they come from are tabled in docs/synthetic_world.md#clutter.

Where things stand (insets are metres from the kerb line into the pavement). Walkers keep to
``world.WALKING_LINES`` with boxes at most 0.47 m to either side (mean + 2 std half width), so
nobody walks nearer the kerb than 0.88 m: that **kerb strip** is the furniture zone, furniture
standing 0.45-0.6 m behind the kerb face. No ground-level part crosses the kerb; only parts
wholly above `shapes.OVERHEAD_CLEARANCE` (4.8 m, above every vehicle box) reach over the
carriageway. Hedges and fences stand at the back of the pavement, in the first 0.5 m of the
setback. Every item is finally tested against the road users' boxes over the whole scene and
the buildings' footprints (`keep_clear`), and dropped if it touches one. Nothing goes within
12.5 m of a junction's centre line along the street except the corner furniture.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from sianms_cli.synth.appearance import sample_appearance
from sianms_cli.synth.road import CROSSING_HALF_WIDTH, PAVEMENT_WIDTH, Route, Street
from sianms_cli.synth.objects import object_parts
from sianms_cli.synth.shapes import STREET_LIGHT_POLE_INSET, Parts, concat_parts, place_parts
from sianms_cli.synth.world import SCENE_SECONDS, Agents, Building

KERB_STRIP = 0.88
"""Pavement depth (m) from the kerb that no walker's box enters (see the module doc)."""
JUNCTION_MARGIN = PAVEMENT_WIDTH + 1.0
"""Along-street distance (m) beyond a crossing street's carriageway kept free of kerb
furniture, hedges and fences: the crossing street's pavement and a metre."""
CORNER_S = CROSSING_HALF_WIDTH + 0.5
"""Along-street distance (m) from a junction's centre to its corner signals."""
TIME_STEP = 0.25
"""Seconds between the road-user poses that `road_user_boxes` samples: the fastest road
user moves 3.5 m between samples, less than a car's length, so the sampled boxes overlap."""

# (w, l, h) ranges (low, high) per kind, metres; w is across the street, l along it.
_SIZE = {
    "tree": ((3.5, 3.5, 7.0), (6.5, 6.5, 12.0)),
    "street_light": ((1.6, 0.4, 8.0), (2.2, 0.4, 10.0)),
    "utility_pole": ((1.6, 0.26, 9.0), (2.0, 0.32, 11.0)),
    "sign": ((0.5, 0.1, 2.7), (0.75, 0.1, 3.0)),
    "traffic_light": ((0.36, 0.4, 3.5), (0.36, 0.4, 3.5)),
    "hydrant": ((0.38, 0.28, 0.65), (0.42, 0.32, 0.8)),
    "bin": ((0.45, 0.45, 0.9), (0.5, 0.5, 1.05)),
    "bollard": ((0.16, 0.16, 0.85), (0.2, 0.2, 1.0)),
    "hedge": ((0.4, 2.5, 0.8), (0.4, 2.5, 1.5)),
    "fence": ((0.06, 2.5, 0.9), (0.06, 2.5, 1.4)),
}
# Inset of each kind's anchor (trunk, pole, post, body centre) from the kerb (m): its
# ground footprint stays inside (0, KERB_STRIP).
_INSET = {"tree": 0.65, "street_light": 0.5, "utility_pole": 0.5, "sign": 0.45, "traffic_light": 0.5,
          "hydrant": 0.5, "bin": 0.55, "bollard": 0.35}
# Along-street clearance (m) an item keeps from the anchors of items placed before it.
_CLEARANCE = {"street_light": 3.0, "utility_pole": 3.0, "tree": 6.0, "sign": 1.0, "hydrant": 3.0,
              "bin": 1.0}


class _Items:
    """Clutter items as columns: kind, size (w, l, h), anchor (the xy of the box's centre
    on the ground), yaw (the box's x along the street, +y away from the road for kerb
    furniture); and per street side the arc lengths of the kerb-strip items, which later
    items keep clear of."""

    def __init__(self) -> None:
        self.kind: list[str] = []
        self.size: list[np.ndarray] = []
        self.anchor: list[np.ndarray] = []
        self.yaw: list[float] = []
        self.strip: dict[int, list[float]] = {+1: [], -1: []}

    def add(self, kind: str, size: np.ndarray, anchor: np.ndarray, yaw: np.ndarray) -> None:
        """One item per row of size (n,3), anchor (n,2) and yaw (n,)."""
        self.kind.extend([kind] * len(size))
        self.size.extend(size)
        self.anchor.extend(anchor)
        self.yaw.extend(float(v) for v in yaw)


@dataclass(frozen=True)
class Clutter:
    """The clutter of one street: kind (n,) of each item, its parts (owner -1, global
    frame) and item (M,) int64, the item index of each part."""

    kind: np.ndarray
    parts: Parts
    item: np.ndarray


def clutter_parts(street: Street, rng: np.random.Generator, buildings: tuple[Building, ...] = (),
                  keep_clear: np.ndarray | None = None) -> Parts:
    """Parts (owner -1, global frame) of the street furniture and vegetation of one street
    (`place_clutter`'s parts)."""
    return place_clutter(street, rng, buildings, keep_clear).parts


def place_clutter(street: Street, rng: np.random.Generator, buildings: tuple[Building, ...] = (),
                  keep_clear: np.ndarray | None = None) -> Clutter:
    """Street furniture and vegetation of one street.

    street: the scene's street (route, cross-section, junctions); rng: this function's own
    stream (same state, same clutter); buildings: the scene's buildings, fronted by hedges
    and fences now and then, and whose footprints are kept clear; keep_clear (K,7) boxes
    x, y, z (centre), w, l, h, yaw in the global frame (`road_user_boxes`): an item
    touching one is left out.
    """
    items = _Items()
    _street_lights(items, street, rng)
    if street.section.drive_side > 0 and rng.random() < 0.5:
        spacing = float(rng.uniform(35.0, 50.0))
        _strip_line(items, street, rng, "utility_pole", int(rng.choice([-1, 1])), spacing)
    for side in (+1, -1):
        if rng.random() < 0.7:
            _strip_line(items, street, rng, "tree", side, float(rng.uniform(8.0, 15.0)), missing=0.1)
        for kind, mean_gap, min_gap in (("sign", 40.0, 10.0), ("hydrant", 200.0, 30.0), ("bin", 80.0, 10.0)):
            _strip_scatter(items, street, rng, kind, side, mean_gap, min_gap)
    _junction_corners(items, street, rng)
    _frontages(items, street, rng, buildings)
    parts, item_of_part = _item_parts(items, rng)
    road_users = np.zeros((0, 7)) if keep_clear is None else np.asarray(keep_clear, np.float64).reshape(-1, 7)
    # Buildings apart from road users: their reach would widen every road user's search.
    touching = np.unique(item_of_part[np.concatenate([_touches(parts, _building_boxes(buildings)),
                                                      _touches(parts, road_users)])])
    kept = np.setdiff1d(np.arange(len(items.kind)), touching)
    keep_part = np.isin(item_of_part, kept)
    renumber = np.searchsorted(kept, item_of_part[keep_part])
    return Clutter(np.array(items.kind, dtype=object)[kept], _select(parts, keep_part), renumber)


def road_user_boxes(agents: Agents, route: Route, seconds: float = SCENE_SECONDS,
                    step: float = TIME_STEP) -> np.ndarray:
    """(K,7) boxes x, y, z, w, l, h, yaw (global frame) of every road user every ``step``
    seconds of a scene ``seconds`` long: what `clutter_parts` keeps clear of."""
    boxes = [np.zeros((0, 7))]
    for t in np.arange(0.0, seconds + 1e-9, step):
        center, yaw, _ = agents.pose(route, float(t))
        boxes.append(np.column_stack([center, agents.size, yaw]))
    return np.concatenate(boxes)


# --- Placement ------------------------------------------------------------------------------

def _sizes(kind: str, rng: np.random.Generator, n: int) -> np.ndarray:
    low, high = (np.array(v) for v in _SIZE[kind])
    return rng.uniform(low, high, (n, 3))


def _put_in_strip(items: _Items, street: Street, rng: np.random.Generator, kind: str, side: int,
                  s: np.ndarray) -> None:
    """Put ``kind`` at arc lengths s in the kerb strip of ``side`` (+1 left of the route,
    -1 right), skipping junctions and spots within `_CLEARANCE` of the strip's items."""
    s = np.sort(s[(s > 0.0) & (s < street.route.length)
                  & ~street.near_intersection(s, JUNCTION_MARGIN)])
    taken = np.array(items.strip[side])
    if len(taken) and len(s):
        s = s[np.abs(s[:, None] - taken[None, :]).min(axis=1) >= _CLEARANCE[kind]]
    if len(s) == 0:
        return
    size = _sizes(kind, rng, len(s))
    xy, heading = street.route.pose(s, side * (street.section.kerb + _INSET[kind]))
    yaw = heading + (np.pi if side < 0 else 0.0)
    if kind == "street_light":
        # The box centre lies towards the road from the pole (shapes.STREET_LIGHT_POLE_INSET).
        shift = size[:, 0] / 2 - STREET_LIGHT_POLE_INSET
        xy = xy - shift[:, None] * np.column_stack([-np.sin(yaw), np.cos(yaw)])
    if kind == "sign":
        # The plate faces the traffic of its side of the road.
        yaw = heading + (0.0 if side * street.section.drive_side > 0 else np.pi)
    items.add(kind, size, xy, yaw)
    items.strip[side].extend(s.tolist())


def _strip_line(items: _Items, street: Street, rng: np.random.Generator, kind: str, side: int,
                spacing: float, missing: float = 0.0) -> None:
    """Evenly spaced ``kind`` along one side, with small setting-out jitter and a share
    ``missing`` of the spots left empty."""
    s = np.arange(float(rng.uniform(0.0, spacing)), street.route.length, spacing)
    s = s + rng.uniform(-0.3, 0.3, len(s))
    _put_in_strip(items, street, rng, kind, side, s[rng.random(len(s)) >= missing])


def _strip_scatter(items: _Items, street: Street, rng: np.random.Generator, kind: str, side: int,
                   mean_gap: float, min_gap: float) -> None:
    """``kind`` at exponential gaps of mean ``mean_gap`` (at least ``min_gap``) along one side."""
    count = int(street.route.length / min_gap) + 2
    gaps = np.maximum(rng.exponential(mean_gap, count), min_gap)
    s = float(rng.uniform(0.0, mean_gap)) + np.concatenate([[0.0], np.cumsum(gaps[:-1])])
    _put_in_strip(items, street, rng, kind, side, s)


def _street_lights(items: _Items, street: Street, rng: np.random.Generator) -> None:
    """Lights 24-40 m apart: staggered on both sides, or on one side only."""
    spacing = float(rng.uniform(24.0, 40.0))
    start = float(rng.uniform(0.0, spacing))
    sides = (+1, -1) if rng.random() < 0.6 else (int(rng.choice([-1, 1])),)
    for k, side in enumerate(sides):
        s = np.arange(start + k * spacing / 2, street.route.length, spacing)
        _put_in_strip(items, street, rng, "street_light", side, s)


def _junction_corners(items: _Items, street: Street, rng: np.random.Generator) -> None:
    """A signal at every corner of every junction, facing the traffic approaching on its
    side; a row of bollards along the kerb beyond it at some corners. The corners lie half
    a metre beyond the route length the junction occupies (its ``half_span``: the crossing
    street's half width where the route goes straight across, the whole turn where it
    turns); the two crossing streets of a 4-way junction where the route turns share one
    set of corners."""
    kerb = street.section.kerb
    done: set[float] = set()
    for junction in street.intersections:
        if junction.s in done:
            continue
        done.add(junction.s)
        corner = junction.half_span + CORNER_S - CROSSING_HALF_WIDTH
        for along in (-1.0, +1.0):
            for side in (+1, -1):
                s = np.array([junction.s + along * corner])
                xy, heading = street.route.pose(s, side * (kerb + _INSET["traffic_light"]))
                items.add("traffic_light", _sizes("traffic_light", rng, 1), xy,
                          heading + (0.0 if along > 0 else np.pi))
                if rng.random() < 0.4:
                    n = int(rng.integers(2, 4))
                    s_row = junction.s + along * (corner + 1.1 + 1.4 * np.arange(n))
                    xy, heading = street.route.pose(s_row, side * (kerb + _INSET["bollard"]))
                    items.add("bollard", _sizes("bollard", rng, n), xy, heading)


def _frontages(items: _Items, street: Street, rng: np.random.Generator, buildings: tuple[Building, ...]) -> None:
    """Hedges or fences along the frontage of some buildings, at the back of the pavement
    (in the first 0.5 m of the setback, so they stand in front of the building's face)."""
    if not buildings:
        return
    centers = np.stack([b.center for b in buildings])
    s_mid, d_mid = street.route.to_route_frame(centers)
    for building, s, d in zip(buildings, s_mid, d_mid):
        if rng.random() >= 0.35:
            continue
        kind = "fence" if rng.random() < 0.25 else "hedge"
        frontage = float(building.size[1])
        n = max(1, int(frontage // _SIZE[kind][0][1]))
        s_panel = s + (np.arange(n) + 0.5 - n / 2) * frontage / n
        s_panel = s_panel[~street.near_intersection(s_panel, JUNCTION_MARGIN)]
        if len(s_panel) == 0:
            continue
        size = _sizes(kind, rng, len(s_panel))
        size[:, 1] = frontage / n - 0.02
        size[:, 2] = size[0, 2]  # one height along a frontage
        side = np.sign(d)
        xy, heading = street.route.pose(s_panel, side * (street.section.pavement_outer + 0.05 + size[:, 0] / 2))
        items.add(kind, size, xy, heading)


# --- Parts and clearance --------------------------------------------------------------------

def _item_parts(items: _Items, rng: np.random.Generator) -> tuple[Parts, np.ndarray]:
    """Every item's parts posed on the ground, and the item index of each part (M,)."""
    placed = []
    for kind, size, anchor, yaw in zip(items.kind, items.size, items.anchor, items.yaw):
        local = object_parts(kind, size, sample_appearance(kind, rng))
        placed.append(place_parts(local, np.array([anchor[0], anchor[1], size[2] / 2]), yaw, -1))
    item_of_part = np.repeat(np.arange(len(placed)), [len(p) for p in placed]).astype(np.int64)
    return concat_parts(placed), item_of_part


def _building_boxes(buildings: tuple[Building, ...]) -> np.ndarray:
    """(B,7) boxes of the buildings' footprints, reaching from far below to far above."""
    if not buildings:
        return np.zeros((0, 7))
    return np.array([[b.center[0], b.center[1], 0.0, b.size[0], b.size[1], 1e4, b.yaw] for b in buildings])


def _touches(parts: Parts, boxes: np.ndarray) -> np.ndarray:
    """Indices of the parts that overlap any of the boxes (K,7) x, y, z, w, l, h, yaw
    (z the box centre): separating-axis test of the footprints where the heights overlap.
    Faces that only touch do not count."""
    if len(parts) == 0 or len(boxes) == 0:
        return np.zeros(0, np.int64)
    box_half = boxes[:, [4, 3]] / 2  # (l, w) / 2 along the box's x, y
    part_reach = np.hypot(parts.half_size[:, 0], parts.half_size[:, 1])
    box_reach = np.hypot(box_half[:, 0], box_half[:, 1])
    tree = cKDTree(boxes[:, :2])
    near = tree.query_ball_point(parts.center[:, :2], part_reach + box_reach.max())
    part = np.repeat(np.arange(len(parts)), [len(n) for n in near])
    box = np.fromiter((k for n in near for k in n), np.int64, len(part))
    z_lo = boxes[box, 2] - boxes[box, 5] / 2
    z_hi = boxes[box, 2] + boxes[box, 5] / 2
    part_lo = parts.center[part, 2] - parts.half_size[part, 2]
    part_hi = parts.center[part, 2] + parts.half_size[part, 2]
    overlap = (part_lo < z_hi) & (z_lo < part_hi)
    overlap &= _footprints_overlap(parts.center[part, :2], parts.half_size[part, :2], parts.yaw[part],
                                   boxes[box, :2], box_half[box], boxes[box, 6])
    return np.unique(part[overlap])


def _footprints_overlap(c1, h1, yaw1, c2, h2, yaw2) -> np.ndarray:
    """Whether pairs of rotated rectangles (centres (n,2), half extents (n,2) along their
    own x and y, yaw (n,)) overlap with positive area: no separating axis among the four
    edge normals."""
    axes1, axes2 = _edge_normals(yaw1), _edge_normals(yaw2)
    delta = c2 - c1
    separated = np.zeros(len(delta), bool)
    for axis in (axes1[0], axes1[1], axes2[0], axes2[1]):
        reach = _projected_half(axes1, h1, axis) + _projected_half(axes2, h2, axis)
        separated |= np.abs(np.einsum("nj,nj->n", delta, axis)) >= reach
    return ~separated


def _edge_normals(yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A rectangle's x and y axes (n,2) each."""
    cos, sin = np.cos(yaw), np.sin(yaw)
    return np.column_stack([cos, sin]), np.column_stack([-sin, cos])


def _projected_half(axes, half: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Half length (n,) of rectangles' projections on unit axes (n,2)."""
    return (half[:, 0] * np.abs(np.einsum("nj,nj->n", axes[0], axis))
            + half[:, 1] * np.abs(np.einsum("nj,nj->n", axes[1], axis)))


def _select(parts: Parts, keep: np.ndarray) -> Parts:
    assert parts.albedo is not None  # Parts.__post_init__ fills it in where not given
    return Parts(parts.center[keep], parts.half_size[keep], parts.yaw[keep], parts.owner[keep],
                 parts.material[keep], parts.albedo[keep])
