"""Paths through a junction where the route goes straight across: turning off the route
into the crossing street and turning from the crossing street onto the route.

A turning road user follows a :class:`~sianms_cli.synth.road.Route` of its own, travelled
forwards at offset 0: a stretch of lane, a 90-degree arc, a stretch of lane. The arc is the
fillet of the two lane centrelines (tangent to both), so the path's heading is continuous
and its speed along the path is the road user's speed. A lane of the route at offset ``d``
is itself a chain of straight and circular pieces (radius ``1/k - d``), so the stretch
along the route is exact on curves too.

Frames: the junction's ``center`` is the route point at its ``s``; ``u`` is the route's
direction there and ``n`` its left normal, which is also the crossing street's direction
(``Intersection.heading`` is the route heading plus 90 degrees). A crossing-street lane at
offset ``q`` from the crossing centreline (positive to the left of ``n``) is the line
``center - q u + y n``.
"""

from __future__ import annotations

import numpy as np

from sianms_cli.synth.road import Intersection, Route

ARM_LENGTH = 150.0  # metres of crossing street on an arm (road.Intersection.along_limits)
LATERAL_ACCELERATION = 3.0
"""m/s^2 in a turn at a town junction: the radius is v^2 / 3, within ``TURN_RADIUS``. Drivers
keep lateral acceleration below about 0.3 g in everyday turns (our estimate; the same bound
as the ego's 12-20 m turns in world.py)."""
TURN_RADIUS = (6.0, 14.0)  # metres: a junction corner fillet to the width of a 4-lane street


def turn_radius(speed: float) -> float:
    """Radius (m) of a 90-degree turn taken at ``speed`` m/s."""
    return float(np.clip(speed * speed / LATERAL_ACCELERATION, *TURN_RADIUS))


def lane_stretch(route: Route, s_from: float, s_to: float, d: float) -> tuple[np.ndarray, np.ndarray]:
    """Lengths (S,) and curvatures (S,) (positive left, in the direction of travel) of the lane
    at offset ``d`` travelled from route arc length ``s_from`` to ``s_to`` (either way)."""
    forward = s_to >= s_from
    lo, hi = min(s_from, s_to), max(s_from, s_to)
    starts = route.starts
    ends = starts + route.lengths
    lengths, curvatures = [], []
    order = range(len(starts)) if forward else range(len(starts) - 1, -1, -1)
    for i in order:
        # The end segments extend beyond the route (as Route.pose does).
        seg_lo = -np.inf if i == 0 else starts[i]
        seg_hi = np.inf if i == len(starts) - 1 else ends[i]
        piece = min(hi, seg_hi) - max(lo, seg_lo)
        if piece <= 1e-9:
            continue
        k = float(route.curvatures[i])
        scale = 1.0 - k * d
        lengths.append(piece * scale)
        curvatures.append((k / scale) * (1.0 if forward else -1.0))
    return np.array(lengths, dtype=float), np.array(curvatures, dtype=float)


def _frame(junction: Intersection) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    heading = junction.heading - np.pi / 2
    u = np.array([np.cos(heading), np.sin(heading)])
    n = np.array([-np.sin(heading), np.cos(heading)])
    return np.asarray(junction.center, dtype=float), u, n


def turn_off_route(route: Route, junction: Intersection, s_start: float, direction: int, d: float,
                   arm: int, arm_lane: float, radius: float) -> tuple[Route, float]:
    """Path of a road user on the route lane at offset ``d`` moving in ``direction`` (+1 along
    increasing ``s``) from arc length ``s_start`` (before the junction), turning into ``arm``
    of the crossing street (+1 along ``n``) in its departing lane at offset ``arm_lane``.
    Returns the path and its length up to the end of the arm."""
    center, u, n = _frame(junction)
    # The lane centrelines meet at x = -arm_lane along u, y = d along n.
    s_arc = junction.s - arm_lane - direction * radius
    stretch, bends = lane_stretch(route, s_start, s_arc, d)
    origin, heading = route.pose(np.array([s_start]), d)
    heading0 = float(heading[0]) + (np.pi if direction < 0 else 0.0)
    sign = direction * arm
    after = ARM_LENGTH - radius - arm * d
    lengths = np.concatenate([stretch, [radius * np.pi / 2, after]])
    curvatures = np.concatenate([bends, [sign / radius, 0.0]])
    return Route(origin[0], heading0, lengths, curvatures), float(lengths.sum())


def turn_onto_route(route: Route, junction: Intersection, arm: int, arm_lane: float, direction: int, d: float,
                    radius: float, s_end: float, arm_length: float = ARM_LENGTH) -> tuple[Route, float]:
    """Path of a road user arriving along ``arm`` of the crossing street (or a driveway) in its
    lane at offset ``arm_lane``, from ``arm_length`` metres out, turning onto the route lane
    at offset ``d`` in ``direction`` and following it to arc length ``s_end``. Returns the
    path and the path length at which its turn begins."""
    center, u, n = _frame(junction)
    # Arriving lane: center - arm_lane u + y n, travelled from y = arm * arm_length towards -arm.
    origin = center - arm_lane * u + arm * arm_length * n
    heading0 = float(np.arctan2(*(-arm * n)[::-1]))
    approach = arm_length - radius - arm * d
    if approach < 0:
        raise ValueError(f"a {radius:.1f} m turn does not fit in {arm_length:.1f} m to the lane at {d:.2f} m")
    s_exit = junction.s - arm_lane + direction * radius
    stretch, bends = lane_stretch(route, s_exit, s_end, d)
    sign = arm * direction
    lengths = np.concatenate([[approach, radius * np.pi / 2], stretch])
    curvatures = np.concatenate([[0.0, sign / radius], bends])
    return Route(origin, heading0, lengths, curvatures), approach
