"""Lane changes, pulling out of and into parking spaces: sideways motion added to a plan
whose paths are already collision-free, and taken back where it would cause a collision.

A manoeuvre is a smoothstep of the lateral offset over 3-6 s (``Agents.shift``), so the
sideways speed starts and ends at zero and the heading follows the path. Since only the
manoeuvring road users leave their lanes, only they are checked: every 0.2 s of the scene,
each body is covered by three circles along its long axis, and a manoeuvre whose circles
come within ``CLEARANCE`` of another body's is reverted (repeated until none does). The ego
changes lane too; the road users its new track would meet are removed from the plan.
"""

from __future__ import annotations

from dataclasses import replace

import numba
import numpy as np

from sianms_cli.synth.road import LANE_WIDTH, Street

EGO_SIZE = np.array([1.73, 4.08, 1.56])  # Renault Zoe w, l, h (nuScenes' car)
CLEARANCE = 0.3  # metres kept between bodies during a manoeuvre
CHECK_STEP = 0.2  # seconds between the checked instants: 2 m at a 10 m/s speed difference
EGO_LANE_CHANGE_SHARE = 0.35
"""Of the straight, moving scenes with two or more lanes each way (~1/3 of the scenes), so ~12 % of
all scenes: with those that turn (`world.TURN_SHARE`), 60-70 % of the scenes are not simply going
straight as `sianms info` measures it (docs/synthetic_world.md#still-short)."""
LANE_CHANGE_SHARE = 0.12  # moving vehicles on two-lane carriageways that change lane in a scene
PULL_OUT_SHARE = 0.06  # cars parked at the kerb that pull out during the scene
PULL_IN_SHARE = 0.04  # vehicles in the kerb-side lane that pull into the parking lane
VEHICLES = ("vehicle.car", "vehicle.truck", "vehicle.bus.rigid", "vehicle.motorcycle")


def plan_manoeuvres(rng: np.random.Generator, street: Street, ego, agents, ego_lane_change: bool, seconds: float):
    """The ego and agents with lane changes and parking manoeuvres added; returns (ego, agents)."""
    original = agents
    agents = _with_lane_changes(rng, street, agents)
    agents = _with_pull_outs(rng, street, agents)
    agents = _with_pull_ins(rng, street, agents)
    if ego_lane_change:
        ego = _ego_lane_change(rng, street, ego)
    times = np.arange(0.0, seconds + 1e-9, CHECK_STEP)
    agents = _revert_conflicts(agents, original, street, ego, times)
    if ego_lane_change:
        agents = without(agents, _conflicts_with_ego(agents, street, ego, times))
    return ego, agents


def _moving_lane_vehicles(street: Street, agents) -> np.ndarray:
    """(N,) bool: moving vehicles on the route, in a driving lane."""
    section = street.section
    lane_centre = section.median / 2 + (section.lane_of(agents.offset) + 0.5) * LANE_WIDTH
    in_lane = np.abs(np.abs(agents.offset) - lane_centre) < 1e-6
    in_lane &= np.abs(agents.offset) < section.bike_lane_inner
    return np.isin(agents.category, VEHICLES) & ~agents.on_line & ~agents.parked & (agents.speed > 0) & in_lane


def _with_lane_changes(rng: np.random.Generator, street: Street, agents):
    """Vehicles on a carriageway of two or more lanes move to the next lane of their direction
    (outwards from lane 0, inwards from the others)."""
    if street.section.lanes_per_direction < 2:
        return agents
    chosen = _moving_lane_vehicles(street, agents) & (rng.random(len(agents)) < LANE_CHANGE_SHARE)
    lane = street.section.lane_of(agents.offset)
    change = np.sign(agents.offset) * np.where(lane == 0, 1, -1) * LANE_WIDTH  # lane 0 -> 1 moves outwards
    shift = agents.shift.copy()
    n = int(chosen.sum())
    shift[chosen] = np.column_stack([change[chosen], rng.uniform(0.0, 16.0, n), rng.uniform(3.0, 6.0, n)])
    return replace(agents, shift=shift)


def _with_pull_outs(rng: np.random.Generator, street: Street, agents):
    """Cars parked at the kerb with the flow wait, then drive off into the kerb-side lane:
    ``stopped`` (driver on board, about to move) until they go."""
    section = street.section
    outer_lane = section.lanes_per_direction - 1
    with_flow = np.sign(agents.offset) == -section.drive_side * agents.direction
    kerb_parked = agents.parked & ~agents.on_line & (np.abs(agents.offset) > section.parking_inner)
    chosen = kerb_parked & with_flow & (agents.category == "vehicle.car") & (rng.random(len(agents)) < PULL_OUT_SHARE)
    n = int(chosen.sum())
    wait = rng.uniform(0.0, 14.0, n)
    speed = rng.uniform(3.0, 6.0, n)
    rows = np.flatnonzero(chosen)
    target = np.array([section.lane_center(outer_lane, int(d)) for d in agents.direction[rows]]).reshape(n)
    p0, p_range, speeds, shift, parked, yaw_offset = (
        agents.p0.copy(), agents.p_range.copy(), agents.speed.copy(), agents.shift.copy(), agents.parked.copy(),
        agents.yaw_offset.copy())
    direction = agents.direction[rows]
    start = p0[rows]
    p0[rows] = start - direction * speed * wait
    p_range[rows] = np.where(direction[:, None] > 0, np.column_stack([start, np.full(n, np.inf)]),
                             np.column_stack([np.full(n, -np.inf), start]))
    speeds[rows] = speed
    shift[rows] = np.column_stack([target - agents.offset[rows], wait, rng.uniform(3.0, 5.0, n)])
    parked[rows] = False
    yaw_offset[rows] = 0.0  # straight, ready to go
    return replace(agents, p0=p0, p_range=p_range, speed=speeds, shift=shift, parked=parked, yaw_offset=yaw_offset)


def _with_pull_ins(rng: np.random.Generator, street: Street, agents):
    """Vehicles in the kerb-side lane pull into the parking lane and stop there."""
    section = street.section
    if not section.parking:
        return agents
    outer = _moving_lane_vehicles(street, agents) & (section.lane_of(agents.offset) == section.lanes_per_direction - 1)
    chosen = outer & (agents.shift[:, 0] == 0.0) & (agents.accel == 0.0) & (rng.random(len(agents)) < PULL_IN_SHARE)
    rows = np.flatnonzero(chosen)
    n = len(rows)
    start = rng.uniform(0.0, 14.0, n)
    duration = rng.uniform(3.5, 5.5, n)
    side = np.sign(agents.offset[rows])
    kerb_offset = side * (section.kerb - np.minimum(agents.size[rows, 0], 2.4) / 2 - 0.2)
    direction = agents.direction[rows]
    stop = agents.p0[rows] + direction * agents.speed[rows] * (start + duration)
    p_range, shift = agents.p_range.copy(), agents.shift.copy()
    p_range[rows] = np.where(direction[:, None] > 0, np.column_stack([np.full(n, -np.inf), stop]),
                             np.column_stack([stop, np.full(n, np.inf)]))
    shift[rows] = np.column_stack([kerb_offset - agents.offset[rows], start, duration])
    return replace(agents, p_range=p_range, shift=shift)


def _ego_lane_change(rng: np.random.Generator, street: Street, ego):
    """The ego moves to the next lane of its direction (outwards from lane 0, else inwards)."""
    lane = int(street.section.lane_of(np.array([ego.offset]))[0])
    change = street.section.lane_center(1 if lane == 0 else lane - 1, +1) - ego.offset
    return replace(ego, shift=(float(change), float(rng.uniform(1.0, 14.0)), float(rng.uniform(3.0, 6.0))))


def _circles(center: np.ndarray, yaw: np.ndarray, size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Three circles (N,3,2) along the long axis of each footprint (centres (N,2)) and their
    radius (N,)."""
    long = np.maximum(size[:, 0], size[:, 1])
    short = np.minimum(size[:, 0], size[:, 1])
    axis = yaw + np.where(size[:, 1] >= size[:, 0], 0.0, np.pi / 2)
    step = (long - short) / 2
    unit = np.stack([np.cos(axis), np.sin(axis)], axis=1)
    offsets = np.array([-1.0, 0.0, 1.0])[None, :, None] * (step[:, None, None] * unit[:, None, :])
    return center[:, None, :] + offsets, short / 2


def closest_approach(agents, street: Street, rows: np.ndarray, times: np.ndarray, ego) -> np.ndarray:
    """(len(rows), N+1) smallest clearance over ``times`` between the bodies of the road users
    ``rows`` and every road user: agents 0..N-1, then the ego (row or column N)."""
    n = len(agents)
    size = np.vstack([agents.size, EGO_SIZE])
    worst = np.full((len(rows), n + 1), np.inf)
    ego_xy, ego_yaw = ego.track(street.route, times)
    for k, t in enumerate(times):
        center, yaw, _ = agents.pose(street.route, float(t))
        center = np.vstack([center[:, :2], ego_xy[k]])
        circles, radius = _circles(center, np.append(yaw, ego_yaw[k]), size)
        _lower_to_clearances(worst, circles, radius, rows)
    worst[np.arange(len(rows)), rows] = np.inf
    return worst


@numba.njit(cache=True)
def _lower_to_clearances(worst, circles, radius, rows):
    """Lower worst (R,M) in place to the clearances between the bodies of road users ``rows``
    (R,) and every road user: the gap between their nearest circles (M,3,2) less both radii (M,)."""
    for i in range(len(rows)):
        a = rows[i]
        for j in range(len(radius)):
            gap = np.inf
            for p in range(3):
                for q in range(3):
                    dx, dy = circles[a, p, 0] - circles[j, q, 0], circles[a, p, 1] - circles[j, q, 1]
                    gap = min(gap, np.sqrt(dx * dx + dy * dy))
            worst[i, j] = min(worst[i, j], gap - radius[a] - radius[j])


def _revert_conflicts(agents, original, street: Street, ego, times: np.ndarray):
    """Take back the manoeuvres that bring their road user within ``CLEARANCE`` of another
    one (or of the ego), until none does; the original plan is collision-free."""
    while True:
        rows = np.flatnonzero(np.any(agents.shift != original.shift, axis=1))
        if len(rows) == 0:
            return agents
        clash = (closest_approach(agents, street, rows, times, ego) < CLEARANCE).any(axis=1)
        if not clash.any():
            return agents
        back = rows[clash]
        agents = replace(agents, **{field: _restored(getattr(agents, field), getattr(original, field), back)
                                    for field in ("p0", "p_range", "speed", "shift", "parked", "yaw_offset")})


def _restored(values: np.ndarray, original: np.ndarray, rows: np.ndarray) -> np.ndarray:
    values = values.copy()
    values[rows] = original[rows]
    return values


def _conflicts_with_ego(agents, street: Street, ego, times: np.ndarray) -> np.ndarray:
    """(N,) bool: agents whose bodies come within ``CLEARANCE`` of the ego's."""
    return closest_approach(agents, street, np.array([len(agents)]), times, ego)[0, :-1] < CLEARANCE


def without(agents, drop: np.ndarray):
    """The agents less those where ``drop`` (N,) is true."""
    keep = ~drop
    return replace(agents, **{name: getattr(agents, name)[keep] for name in agents.__dataclass_fields__})
