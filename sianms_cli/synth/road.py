"""The street the ego drives: a route of straight and curved segments, its cross-section,
the crossing streets of intersections (straight-through crossings and the junctions where
the route itself turns), car parks beside it, and the ground's look and LiDAR reflectivity.

Route coordinates: ``s`` is the arc length along the route centreline (metres) and ``d``
the signed lateral offset, positive to the left of the direction of travel. The ground is
the plane z = 0 of the global frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numba
import numpy as np

LANE_WIDTH = 3.5
BIKE_LANE_WIDTH = 1.5
PARKING_WIDTH = 2.4
PAVEMENT_WIDTH = 4.5
CROSSING_HALF_WIDTH = 7.0
ZEBRA_DEPTH = 4.0
STOP_LINE_GAP = 1.0
BAY_WIDTH = 2.6  # metres between car-park bay lines, square to the lines
BAY_DEPTH = 5.0
CAR_PARK_BORDER = 0.6
"""Metres of verge between the pavement and a car park's asphalt: room for the hedges and
fences that stand at the back of the pavement."""
BAY_START = CAR_PARK_BORDER + 0.5  # where the bays begin, from the pavement's outer edge
AISLE_WIDTH = 6.0
"""Metres of driving aisle between two rows of bays (6-7 m is common practice for 90-degree
bays; one-way aisles of angled bays are narrower, one width keeps the layout simple)."""
ROW_PITCH = BAY_DEPTH + AISLE_WIDTH  # from one row of bays to the next, across the car park

SURFACE_TINT = np.array([[1.0, 1.0, 1.04], [1.0, 0.98, 0.94], [0.55, 1.0, 0.35], [1.0, 0.92, 0.82]])
"""Colour tint of asphalt, pavement, grass and plaza, multiplied by a per-point grey level."""
PAINT_COLOUR = np.array([[0.75, 0.75, 0.72], [0.7, 0.5, 0.08]])  # white, yellow


@dataclass(frozen=True)
class CrossSection:
    """Lanes from the centreline outwards, the same on both sides of the road; an arterial
    has a planted median of width ``median`` between its carriageways (0: none)."""

    lanes_per_direction: int
    parking: bool
    drive_side: int  # +1: traffic keeps right (Boston), -1: keeps left (Singapore)
    median: float = 0.0

    @property
    def bike_lane_inner(self) -> float:
        return self.median / 2 + self.lanes_per_direction * LANE_WIDTH

    @property
    def parking_inner(self) -> float:
        return self.bike_lane_inner + BIKE_LANE_WIDTH

    @property
    def kerb(self) -> float:
        """Distance from the centreline to the kerb: where the pavement starts."""
        return self.parking_inner + (PARKING_WIDTH if self.parking else 0.0)

    @property
    def pavement_outer(self) -> float:
        return self.kerb + PAVEMENT_WIDTH

    def lane_center(self, lane: int, direction: int) -> float:
        """Lateral offset ``d`` of driving lane ``lane`` (0 = next to the centreline) used by
        traffic moving in ``direction`` (+1 along increasing ``s``, -1 against it)."""
        side = -self.drive_side * direction
        return side * (self.median / 2 + (lane + 0.5) * LANE_WIDTH)

    def lane_of(self, offset: np.ndarray) -> np.ndarray:
        """Lane index (0 next to the centreline or the median) of lane-centre offsets ``d`` (N,)."""
        return np.rint((np.abs(offset) - self.median / 2) / LANE_WIDTH - 0.5).astype(int)


@dataclass(frozen=True)
class Route:
    """A centreline made of constant-curvature segments.

    ``lengths (S,)`` and ``curvatures (S,)`` (1/m, positive turns left) describe the
    segments in order, starting at ``origin (2,)`` with heading ``heading0`` (radians,
    counter-clockwise from global +x).
    """

    origin: np.ndarray
    heading0: float
    lengths: np.ndarray
    curvatures: np.ndarray

    @cached_property
    def starts(self) -> np.ndarray:
        """(S,) arc length at which each segment starts (computed once: see _segment_starts)."""
        return np.concatenate([[0.0], np.cumsum(self.lengths)[:-1]])

    @property
    def length(self) -> float:
        return float(np.sum(self.lengths))

    @cached_property
    def _segment_starts(self) -> tuple[np.ndarray, np.ndarray]:
        """Start point (S,2) and start heading (S,) of every segment (computed once: every
        pose needs them, and planning and sensing ask for ~10^4 poses a scene)."""
        headings = self.heading0 + np.concatenate(
            [[0.0], np.cumsum(self.lengths * self.curvatures)[:-1]]
        )
        points = np.empty((len(self.lengths), 2))
        point = np.asarray(self.origin, dtype=float)
        for i, (length, curvature, heading) in enumerate(zip(self.lengths, self.curvatures, headings)):
            points[i] = point
            point = point + _advance(length, curvature, heading)
        return points, headings

    def point(self, s: float) -> tuple[float, float, float]:
        """x, y and heading of the centreline at one arc length ``s`` (as :meth:`pose`, in plain
        floats: far faster for a single point, which the turning road users' poses need)."""
        points, headings = self._segment_starts
        starts = self.starts
        i = min(max(int(np.searchsorted(starts, s, side="right")) - 1, 0), len(starts) - 1)
        u = s - float(starts[i])
        k = float(self.curvatures[i])
        h0 = float(headings[i])
        x0, y0 = float(points[i, 0]), float(points[i, 1])
        if abs(k) < 1e-9:
            return x0 + u * math.cos(h0), y0 + u * math.sin(h0), h0
        return (x0 + (math.sin(h0 + k * u) - math.sin(h0)) / k, y0 + (math.cos(h0) - math.cos(h0 + k * u)) / k,
                h0 + k * u)

    def curvature_at(self, s: np.ndarray) -> np.ndarray:
        """Curvature (N,) 1/m of the centreline at arc lengths ``s`` (the end segments extend)."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        index = np.clip(np.searchsorted(self.starts, s, side="right") - 1, 0, len(self.lengths) - 1)
        return self.curvatures[index]

    def pose(self, s: np.ndarray, d: np.ndarray | float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Global xy (N,2) and heading (N,) of the points at arc length ``s`` and offset ``d``.

        ``s`` outside [0, length] extends the first or last segment.
        """
        s = np.atleast_1d(np.asarray(s, dtype=float))
        points, headings = self._segment_starts
        index = np.clip(np.searchsorted(self.starts, s, side="right") - 1, 0, len(self.lengths) - 1)
        u = s - self.starts[index]
        curvature = self.curvatures[index]
        start_heading = headings[index]
        xy = points[index] + _advance(u, curvature, start_heading).T.reshape(-1, 2)
        heading = start_heading + curvature * u
        normal = np.stack([-np.sin(heading), np.cos(heading)], axis=-1)
        return xy + normal * np.asarray(d, dtype=float)[..., None], heading

    def to_route_frame(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Arc length ``s`` (P,) and offset ``d`` (P,) of the nearest centreline point of each xy (P,2)."""
        xy = np.asarray(xy, dtype=float)
        x, y = xy[:, 0], xy[:, 1]
        points, headings = self._segment_starts
        best_s = np.zeros(len(xy))
        best_d = np.full(len(xy), np.inf)
        best_cost = np.full(len(xy), np.inf)
        for start, point, heading, length, curvature in zip(
            self.starts, points, headings, self.lengths, self.curvatures
        ):
            u, d = _segment_coordinates(x, y, point, heading, length, curvature)
            _keep_nearer(u, d, start, length, best_cost, best_s, best_d)
        return best_s, best_d


@numba.njit(cache=True)
def _straight_coordinates(x, y, x0, y0, cos, sin):
    """Coordinates along (u) and across (d) a straight segment from (x0, y0) heading (cos, sin)
    of points (x, y) (P,)."""
    u, d = np.empty(len(x)), np.empty(len(x))
    for i in range(len(x)):
        dx, dy = x[i] - x0, y[i] - y0
        u[i] = dx * cos + dy * sin
        d[i] = -dx * sin + dy * cos
    return u, d


@numba.njit(cache=True)
def _keep_nearer(u, d, start, length, best_cost, best_s, best_d):
    """Make a segment the nearest so far (best_cost, best_s, best_d (P,), in place) of the points
    nearer to it than to every earlier one: u, d (P,) their coordinates along and across it
    (finite), start its arc length along the route."""
    for i in range(len(u)):
        excess = max(-u[i], u[i] - length, 0.0)
        cost = excess * excess + d[i] * d[i]  # squared distance: same order, no square root
        if cost < best_cost[i]:
            best_cost[i] = cost
            best_s[i] = start + min(max(u[i], 0.0), length)
            best_d[i] = d[i]


def _advance(u: np.ndarray | float, curvature: np.ndarray | float, heading: np.ndarray | float) -> np.ndarray:
    """Displacement (2, ...) after travelling ``u`` on a constant-curvature arc."""
    u, curvature, heading = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (u, curvature, heading)))
    straight = np.abs(curvature) < 1e-9
    safe = np.where(straight, 1.0, curvature)
    dx = np.where(straight, u * np.cos(heading), (np.sin(heading + safe * u) - np.sin(heading)) / safe)
    dy = np.where(straight, u * np.sin(heading), (np.cos(heading) - np.cos(heading + safe * u)) / safe)
    return np.stack([dx, dy])


def _segment_coordinates(
    x: np.ndarray, y: np.ndarray, start: np.ndarray, heading: float, length: float, curvature: float
) -> tuple[np.ndarray, np.ndarray]:
    """Unclipped arc length ``u`` along one segment and lateral offset ``d`` of points (x, y) (P,)."""
    if abs(curvature) < 1e-9:
        return _straight_coordinates(x, y, start[0], start[1], np.cos(heading), np.sin(heading))
    radius = 1.0 / curvature
    center = start + radius * np.array([-np.sin(heading), np.cos(heading)])
    dx, dy = x - center[0], y - center[1]
    start_angle = np.arctan2(*(start - center)[::-1])
    angle = np.arctan2(dy, dx)
    # Unwrap around the middle of the arc so that points before its start get u < 0.
    middle = start_angle + curvature * length / 2
    swept = _wrap(angle - middle + np.pi, 2 * np.pi) - np.pi + (middle - start_angle)
    u = swept / curvature
    d = np.sign(curvature) * (abs(radius) - np.hypot(dx, dy))
    return u, d


@dataclass(frozen=True)
class Intersection:
    """A straight crossing street through the route point at arc length ``s``.

    Where the route goes straight across, the crossing street has both arms, or one at a side
    street (``side_street``, a T junction the route goes straight past). Where the route
    turns at a junction, ``s`` is the middle of the turn, ``center`` the corner where the
    incoming and outgoing centrelines meet, and the crossing street has only the arms
    that are not the route: a T junction is one crossing street along the outgoing road with
    the arm behind it; a 4-way junction adds a second one along the incoming road with the
    arm beyond it. ``half_span`` is the half length of route that the junction occupies.
    """

    s: float
    center: np.ndarray  # (2,) global xy
    heading: float  # direction of the crossing street, radians
    arms: tuple[int, ...] = (-1, 1)  # +1: the arm along ``heading``, -1: the arm behind it
    half_span: float = CROSSING_HALF_WIDTH
    side_street: bool = False  # a T junction the route goes straight past: one arm, the route straight on

    @property
    def through(self) -> bool:
        """The route goes straight across (or past a side street): zebras and stop lines on
        both sides of it."""
        return len(self.arms) == 2 or self.side_street

    def along_limits(self) -> tuple[float, float]:
        """Range of the along-street coordinate that the crossing street covers: 150 m each
        way on an arm, up to the junction's far edge where there is no arm."""
        return (-150.0 if -1 in self.arms else -CROSSING_HALF_WIDTH,
                150.0 if 1 in self.arms else CROSSING_HALF_WIDTH)


@dataclass(frozen=True)
class CarPark:
    """Open parking beside the road, behind the pavement: route arc lengths [s0, s1] on
    ``side`` (+1 left, -1 right), ``depth`` metres deep from the pavement's outer edge (the
    first ``CAR_PARK_BORDER`` of it verge, then asphalt), ``rows`` rows of bays ``ROW_PITCH``
    apart at ``angle`` to the direction of increasing ``s`` (pi/2: perpendicular)."""

    side: int
    s0: float
    s1: float
    depth: float
    angle: float
    rows: int = 1

    def in_bay_row(self, across: np.ndarray) -> np.ndarray:
        """Whether distances ``across`` from the pavement's outer edge fall inside a row of bays."""
        into = across - BAY_START
        return (into > 0.0) & (np.mod(into, ROW_PITCH) < BAY_DEPTH) & (into < (self.rows - 1) * ROW_PITCH + BAY_DEPTH)

    @property
    def bay_spacing(self) -> float:
        """Distance along the road between neighbouring bays."""
        return BAY_WIDTH / np.sin(self.angle)


@dataclass(frozen=True)
class Street:
    """Everything about the road surface a renderer and a LiDAR need."""

    route: Route
    section: CrossSection
    intersections: tuple[Intersection, ...]
    center_line_yellow: bool
    car_parks: tuple[CarPark, ...] = ()

    def crossing_streets(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Whether ground points (P,2) lie on a crossing street's carriageway, on its pavement,
        inside a junction (its carriageway between the route's kerbs) and on its dashed centre
        line: four (P,) masks, each over every crossing street."""
        xy = np.asarray(xy, dtype=float)
        return _crossing_streets(np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]),
                                 *self._crossing_frames, self.section.kerb)

    @cached_property
    def _crossing_frames(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The crossing streets' centres (K,2), the cosine and sine of their headings (K,) and
        their along-street limits (K,2): what every ground look-up of the street reads."""
        headings = np.array([i.heading for i in self.intersections], dtype=float)
        return (np.array([i.center for i in self.intersections], dtype=float).reshape(-1, 2), np.cos(headings),
                np.sin(headings), np.array([i.along_limits() for i in self.intersections], dtype=float).reshape(-1, 2))

    def near_intersection(self, s: np.ndarray, margin: float) -> np.ndarray:
        """Whether route arc lengths ``s`` lie within a junction (the crossing street, or the
        whole turn where the route turns) plus ``margin``."""
        s = np.asarray(s, dtype=float)
        near = np.zeros(s.shape, dtype=bool)
        for intersection in self.intersections:
            near |= np.abs(s - intersection.s) < intersection.half_span + margin
        return near

    def in_car_park(self, s: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Whether route coordinates (P,) lie on a car park's surface."""
        inside = np.zeros(np.shape(s), dtype=bool)
        outer = self.section.pavement_outer
        for park in self.car_parks:
            across = park.side * d - outer
            inside |= (s > park.s0) & (s < park.s1) & (across > CAR_PARK_BORDER) & (across < park.depth)
        return inside

    def surface(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Surface class (P,) int8, paint mask (P,) bool and yellow-paint mask (P,) bool of
        ground points (P,2). Classes: 0 asphalt, 1 pavement, 2 verge (grass or plaza).
        """
        s, d = self.route.to_route_frame(xy)
        on_crossing, crossing_pavement, in_junction, crossing_dashes = self.crossing_streets(xy)
        kerb = self.section.kerb
        abs_d = np.abs(d)
        klass = np.full(len(xy), 2, dtype=np.int8)
        klass[(abs_d < self.section.pavement_outer) | crossing_pavement] = 1
        klass[(abs_d < kerb) | on_crossing | self.in_car_park(s, d)] = 0
        if self.section.median > 0:
            klass[(abs_d < self.section.median / 2 - 0.3) & ~on_crossing] = 2  # planted median

        on_route_road = ~in_junction & (abs_d < kerb)
        center_line = self._center_line(s, d) & on_route_road
        markings = center_line | (self._lane_markings(s, d) & on_route_road) | self._zebras(s, d)
        markings |= self._bay_lines(s, d)
        markings |= crossing_dashes
        yellow = center_line if self.center_line_yellow else np.zeros_like(center_line)
        return klass, markings, yellow

    def _center_line(self, s: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Double solid line (Boston style) or a single dashed line (Singapore style); beside
        a median, a solid edge line along each side of it."""
        if self.section.median > 0:
            return np.abs(np.abs(d) - self.section.median / 2) < 0.08
        if self.center_line_yellow:
            return np.abs(np.abs(d) - 0.15) < 0.06
        return (np.abs(d) < 0.08) & _dashes(s, 3.0, 6.0)

    def _lane_markings(self, s: np.ndarray, d: np.ndarray) -> np.ndarray:
        section = self.section
        abs_d = np.abs(d)
        dividers = np.zeros(s.shape, dtype=bool)
        for lane in range(1, section.lanes_per_direction):
            dividers |= (np.abs(abs_d - section.median / 2 - lane * LANE_WIDTH) < 0.07) & _dashes(s, 3.0, 6.0)
        bike_line = np.abs(abs_d - section.bike_lane_inner) < 0.08
        parking_line = (np.abs(abs_d - section.parking_inner) < 0.06) & section.parking
        stop_lines = np.zeros(s.shape, dtype=bool)
        for intersection in (i for i in self.intersections if i.through):
            for sign in (-1.0, 1.0):
                edge = intersection.s + sign * (CROSSING_HALF_WIDTH + ZEBRA_DEPTH + STOP_LINE_GAP)
                lane_side = np.sign(d) == sign * section.drive_side
                stop_lines |= (np.abs(s - edge) < 0.25) & lane_side & (abs_d < section.bike_lane_inner)
        return dividers | bike_line | parking_line | stop_lines

    def _zebras(self, s: np.ndarray, d: np.ndarray) -> np.ndarray:
        zebra = np.zeros(s.shape, dtype=bool)
        for intersection in (i for i in self.intersections if i.through):
            offset = np.abs(s - intersection.s) - CROSSING_HALF_WIDTH
            band = (offset > 0.5) & (offset < 0.5 + ZEBRA_DEPTH - 1.0)
            zebra |= band & (np.abs(d) < self.section.kerb) & (_wrap(d, 1.0) < 0.5)
        return zebra

    def _bay_lines(self, s: np.ndarray, d: np.ndarray) -> np.ndarray:
        """White lines between the car parks' bays, slanted at the bays' angle."""
        lines = np.zeros(s.shape, dtype=bool)
        outer = self.section.pavement_outer
        for park in self.car_parks:
            alongside = np.flatnonzero((s > park.s0) & (s < park.s1))  # the rest of the ground is no bay
            across = park.side * d[alongside] - outer
            # Every row repeats the first one's lines, so its bays lie straight behind them.
            in_row = np.mod(across - BAY_START, ROW_PITCH) + BAY_START
            slanted = s[alongside] - park.s0 - in_row / np.tan(park.angle)
            lines[alongside] |= park.in_bay_row(across) & (_wrap(slanted, park.bay_spacing) < 0.12)
        return lines

    def ground_albedo(self, xy: np.ndarray) -> np.ndarray:
        """Linear RGB albedo (P,3) in [0, 1] of ground points (P,2): asphalt, pavement, verge, paint.

        One grey level per point for its own surface, times the surface's tint: cheaper than
        blending full colour images of every surface, which matters at ~10^5 pixels a frame.
        """
        xy = np.asarray(xy, dtype=float)
        klass, markings, yellow = self.surface(xy)
        fine = value_noise(xy, 0.35, seed=11)
        coarse = value_noise(xy, 4.0, seed=23)
        kind = klass.astype(np.intp)
        level = np.where(klass == 0, 0.055 + 0.03 * coarse + 0.02 * fine, 0.21 + 0.05 * coarse + 0.03 * fine)
        verge = np.flatnonzero(klass == 2)
        if len(verge):
            grass = value_noise(xy[verge], 40.0, seed=5) > 0.5
            c, f = coarse[verge], fine[verge]
            level[verge] = np.where(grass, 0.05 + 0.05 * c + 0.03 * f, 0.16 + 0.04 * c + 0.03 * f)
            kind[verge] = np.where(grass, 2, 3)
        pavement = np.flatnonzero(klass == 1)
        level[pavement] -= 0.06 * _pavement_joints(xy[pavement])
        tint = SURFACE_TINT[kind]
        paint = np.flatnonzero(markings)
        level[paint] = 0.85 + 0.15 * fine[paint]
        tint[paint] = PAINT_COLOUR[yellow[paint].astype(np.intp)]
        return np.clip(tint * level[:, None], 0.0, 1.0)

    def ground_reflectivity(self, xy: np.ndarray) -> np.ndarray:
        """LiDAR reflectivity (P,) in [0, 1]: paint is retro-reflective, asphalt dark."""
        klass, markings, _ = self.surface(np.asarray(xy, dtype=float))
        base = np.array([0.08, 0.2, 0.14])[klass]
        return np.where(markings, 0.65, base)


def _wrap(x: np.ndarray, period: float) -> np.ndarray:
    """``x`` modulo ``period`` in [0, period): numpy's float ``%`` is much slower than this."""
    return x - np.floor(x / period) * period


@numba.njit(cache=True)
def _crossing_streets(x, y, centers, cos, sin, limits, kerb):
    """:meth:`Street.crossing_streets` of points (x, y) (P,) and K crossing streets: centres
    (K,2), the cosine and sine of their headings (K,), their along-street limits (K,2)."""
    on_crossing = np.zeros(len(x), np.bool_)
    pavement = np.zeros(len(x), np.bool_)
    junction = np.zeros(len(x), np.bool_)
    dashes = np.zeros(len(x), np.bool_)
    for i in range(len(x)):
        for k in range(len(cos)):
            dx, dy = x[i] - centers[k, 0], y[i] - centers[k, 1]
            along = dx * cos[k] + dy * sin[k]
            across = -dx * sin[k] + dy * cos[k]
            if not (along > limits[k, 0] and along < limits[k, 1]):
                continue
            if abs(across) < CROSSING_HALF_WIDTH:
                on_crossing[i] = True
                junction[i] |= abs(along) < kerb
                dash = along - np.floor(along / 9.0) * 9.0 < 3.0  # _dashes(along, 3.0, 6.0)
                dashes[i] |= abs(along) > kerb and dash and abs(across) < 0.08
            pavement[i] |= abs(across) < CROSSING_HALF_WIDTH + PAVEMENT_WIDTH and abs(along) > kerb
    return on_crossing, pavement, junction, dashes


def _dashes(u: np.ndarray, on: float, off: float) -> np.ndarray:
    return _wrap(u, on + off) < on


def _pavement_joints(xy: np.ndarray) -> np.ndarray:
    """1 on the joints of a 1.5 m concrete slab grid in global axes, else 0."""
    return (_wrap(xy, 1.5) < 0.04).any(axis=1).astype(float)


def value_noise(xy: np.ndarray, scale: float, seed: int) -> np.ndarray:
    """Smooth deterministic noise in [0, 1] over the plane, features of ``scale`` metres.

    Bilinear interpolation of hashed lattice values, so the ground looks the same from
    every camera and every frame without storing a texture.
    """
    xy = np.asarray(xy, dtype=float)
    return _value_noise(np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]), float(scale), seed)


@numba.njit(cache=True)
def _value_noise(x, y, scale, seed):
    """:func:`value_noise` of points (x, y) (P,)."""
    noise = np.empty(len(x))
    for i in range(len(x)):
        gx, gy = x[i] / scale, y[i] / scale
        cx, cy = np.floor(gx), np.floor(gy)
        fx, fy = gx - cx, gy - cy
        fx = fx * fx * (3.0 - 2.0 * fx)  # smoothstep: no crease at the lattice lines
        fy = fy * fy * (3.0 - 2.0 * fy)
        ix, iy = np.int64(cx), np.int64(cy)
        bottom = _hash01(ix, iy, seed) * (1.0 - fx) + _hash01(ix + 1, iy, seed) * fx
        top = _hash01(ix, iy + 1, seed) * (1.0 - fx) + _hash01(ix + 1, iy + 1, seed) * fx
        noise[i] = bottom * (1.0 - fy) + top * fy
    return noise


@numba.njit(cache=True, inline="always")
def _hash01(ix, iy, seed):
    """Integer lattice hash to [0, 1) (a 64-bit mix, stable across platforms)."""
    h = np.uint64(ix) * np.uint64(0x9E3779B97F4A7C15)
    h ^= np.uint64(iy) * np.uint64(0xC2B2AE3D27D4EB4F) + np.uint64(seed)
    h ^= h >> np.uint64(31)
    h *= np.uint64(0xBF58476D1CE4E5B9)
    h ^= h >> np.uint64(29)
    return np.float64(h >> np.uint64(11)) / 9007199254740992.0  # 2 ** 53
