"""Traffic of one synthetic scene: the ego's drive and every other road user, as paths.

An agent moves along a *path*: the route with a lateral offset (lanes, bike lanes,
pavements, parking lanes) or a straight line (a crossing street). Its position on the
path at time ``t`` is ``clip(p0 + direction * (v t + a t^2 / 2), p_min, p_max)``, so speed
and heading are consistent between keyframes by construction, and agents that share a
lane share its speed, which keeps them from driving into one another.

Class mix and density target the nuScenes trainval statistics collected in
``shared/reference/nuscenes.md`` §9 (objects per keyframe: cars 14.4, pedestrians 6.4,
barriers 4.5, cones 2.9, trucks 2.6, buses 0.5, bicycles 0.35, motorcycles 0.37; moving
object speeds: car 6.6 m/s, pedestrian 1.3 m/s, bicycle 4 m/s; vehicle attributes
parked / moving / stopped ≈ 52 / 30 / 17 %; ego at 16 km/h on average). ``sianms info``
prints what a generated dataset actually holds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sianms_cli.synth.road import (
    LANE_WIDTH,
    PARKING_WIDTH,
    PAVEMENT_WIDTH,
    CrossSection,
    Intersection,
    Route,
    Street,
)

SCENE_SECONDS = 20.0
KEYFRAME_HZ = 2.0
ANNOTATION_RADIUS = 80.0  # metres from the ego: nuScenes car annotations reach ~80 m
ROUTE_MARGIN = 160.0  # route length before and after the ego's drive

# (w, l, h) mean and std per category, nuScenes trainval (reference §9.3).
SIZE_STATS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "vehicle.car": ((1.95, 4.62, 1.73), (0.19, 0.46, 0.24)),
    "vehicle.truck": ((2.51, 6.93, 2.84), (0.45, 2.17, 0.84)),
    "vehicle.bus.rigid": ((2.93, 11.23, 3.47), (0.33, 2.07, 0.52)),
    "vehicle.motorcycle": ((0.77, 2.11, 1.47), (0.17, 0.32, 0.23)),
    "vehicle.bicycle": ((0.60, 1.70, 1.28), (0.16, 0.26, 0.34)),
    "human.pedestrian.adult": ((0.67, 0.73, 1.77), (0.13, 0.19, 0.18)),
    "human.pedestrian.child": ((0.51, 0.53, 1.38), (0.14, 0.15, 0.25)),
    "human.pedestrian.construction_worker": ((0.72, 0.71, 1.74), (0.20, 0.20, 0.30)),
    "movable_object.barrier": ((2.53, 0.50, 0.98), (0.64, 0.17, 0.15)),
    "movable_object.trafficcone": ((0.41, 0.41, 1.07), (0.13, 0.14, 0.27)),
}

SHAPE_KIND = {
    "vehicle.car": "car",
    "vehicle.truck": "truck",
    "vehicle.bus.rigid": "bus",
    "vehicle.motorcycle": "motorcycle",
    "vehicle.bicycle": "bicycle",
    "human.pedestrian.adult": "pedestrian",
    "human.pedestrian.child": "pedestrian",
    "human.pedestrian.construction_worker": "pedestrian",
    "movable_object.barrier": "barrier",
    "movable_object.trafficcone": "traffic_cone",
}

MOVING_SPEED = 0.2  # m/s: below this a road user counts as standing still


@dataclass
class AgentList:
    """Columns of the agents of a scene while they are being placed."""

    category: list
    size: list
    path_line: list  # (origin x, origin y, heading) for straight paths, None for the route
    offset: list  # lateral offset d on the route (route paths)
    p0: list
    speed: list
    accel: list
    direction: list
    p_range: list  # (p_min, p_max)
    yaw_offset: list
    parked: list
    rider: list

    @classmethod
    def empty(cls) -> "AgentList":
        return cls(*([] for _ in range(12)))

    def add(self, category, size, *, p0, offset=0.0, line=None, speed=0.0, accel=0.0, direction=1,
            p_range=(-np.inf, np.inf), yaw_offset=0.0, parked=False, rider=False) -> None:
        self.category.append(category)
        self.size.append(np.asarray(size, dtype=float))
        self.path_line.append(line)
        self.offset.append(offset)
        self.p0.append(p0)
        self.speed.append(speed)
        self.accel.append(accel)
        self.direction.append(direction)
        self.p_range.append(p_range)
        self.yaw_offset.append(yaw_offset)
        self.parked.append(parked)
        self.rider.append(rider)


@dataclass(frozen=True)
class Agents:
    """The N road users of a scene as aligned arrays; ``pose(t)`` evaluates their paths."""

    category: np.ndarray  # (N,) nuScenes category names
    size: np.ndarray  # (N,3) w, l, h in metres
    on_line: np.ndarray  # (N,) bool: straight path instead of the route
    line: np.ndarray  # (N,3) origin x, y and heading of straight paths
    offset: np.ndarray  # (N,) lateral route offset d
    p0: np.ndarray
    speed: np.ndarray
    accel: np.ndarray
    direction: np.ndarray  # (N,) +1 / -1 along the path
    p_range: np.ndarray  # (N,2)
    yaw_offset: np.ndarray
    parked: np.ndarray  # (N,) bool
    rider: np.ndarray  # (N,) bool: cycles carrying a rider

    @classmethod
    def from_list(cls, agents: AgentList) -> "Agents":
        n = len(agents.category)
        line = np.array([l if l is not None else (0.0, 0.0, 0.0) for l in agents.path_line]).reshape(n, 3)
        return cls(
            category=np.array(agents.category, dtype=object),
            size=np.array(agents.size).reshape(n, 3),
            on_line=np.array([l is not None for l in agents.path_line], dtype=bool),
            line=line,
            offset=np.array(agents.offset, dtype=float),
            p0=np.array(agents.p0, dtype=float),
            speed=np.array(agents.speed, dtype=float),
            accel=np.array(agents.accel, dtype=float),
            direction=np.array(agents.direction, dtype=float),
            p_range=np.array(agents.p_range, dtype=float).reshape(n, 2),
            yaw_offset=np.array(agents.yaw_offset, dtype=float),
            parked=np.array(agents.parked, dtype=bool),
            rider=np.array(agents.rider, dtype=bool),
        )

    def __len__(self) -> int:
        return len(self.category)

    def path_position(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Path coordinate (N,) and speed along the path (N,) m/s at time ``t`` seconds."""
        travelled = self.speed * t + 0.5 * self.accel * t * t
        raw = self.p0 + self.direction * travelled
        clipped = np.clip(raw, self.p_range[:, 0], self.p_range[:, 1])
        speed = np.where(clipped == raw, np.abs(self.speed + self.accel * t), 0.0)
        return clipped, speed

    def pose(self, route: Route, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Box centres (N,3) global, yaw (N,) and ground speed (N,) m/s at time ``t``."""
        p, speed = self.path_position(t)
        xy_route, heading_route = route.pose(p, self.offset)
        heading_line = self.line[:, 2]
        xy_line = self.line[:, :2] + p[:, None] * np.stack([np.cos(heading_line), np.sin(heading_line)], axis=1)
        xy = np.where(self.on_line[:, None], xy_line, xy_route)
        heading = np.where(self.on_line, heading_line, heading_route)
        yaw = heading + np.where(self.direction < 0, np.pi, 0.0) + self.yaw_offset
        yaw = np.mod(yaw + np.pi, 2 * np.pi) - np.pi
        center = np.column_stack([xy, self.size[:, 2] / 2])
        return center, yaw, speed

    def attributes(self, speed: np.ndarray) -> np.ndarray:
        """nuScenes attribute name (N,) ("" for none) for ground speeds (N,)."""
        moving = speed > MOVING_SPEED
        names = np.full(len(self), "", dtype=object)
        category = self.category
        vehicle = np.isin(category, ["vehicle.car", "vehicle.truck", "vehicle.bus.rigid"])
        names[vehicle] = np.where(moving[vehicle], "vehicle.moving",
                                  np.where(self.parked[vehicle], "vehicle.parked", "vehicle.stopped"))
        cycle = np.isin(category, ["vehicle.bicycle", "vehicle.motorcycle"])
        names[cycle] = np.where(self.rider[cycle], "cycle.with_rider", "cycle.without_rider")
        pedestrian = np.array([c.startswith("human.pedestrian") for c in category], dtype=bool)
        names[pedestrian] = np.where(moving[pedestrian], "pedestrian.moving", "pedestrian.standing")
        return names


@dataclass(frozen=True)
class Building:
    """A block beside the road: footprint centre (2,), yaw of its frontage, and its size
    (w, l, h) = (depth, frontage, height) in the object convention (x along the frontage)."""

    center: np.ndarray
    yaw: float
    size: np.ndarray


@dataclass(frozen=True)
class EgoDrive:
    """The ego vehicle's motion along its lane: s(t) = s0 + v t + a t^2 / 2."""

    s0: float
    speed: float
    accel: float
    offset: float

    def s(self, t: float | np.ndarray) -> np.ndarray:
        return self.s0 + self.speed * np.asarray(t) + 0.5 * self.accel * np.asarray(t) ** 2

    def pose(self, route: Route, t: float) -> tuple[np.ndarray, float]:
        """Ego xy (2,) and yaw at time ``t``."""
        xy, heading = route.pose(self.s(t), self.offset)
        return xy[0], float(heading[0])


@dataclass(frozen=True)
class ScenePlan:
    """Everything that happens in one scene, decided before anything is rendered."""

    street: Street
    ego: EgoDrive
    agents: Agents
    buildings: tuple[Building, ...]
    busyness: float
    roadworks: bool

    @property
    def route(self) -> Route:
        return self.street.route


def sample_size(category: str, rng: np.random.Generator) -> np.ndarray:
    """(w, l, h) drawn from a normal per dimension, clipped to two standard deviations."""
    mean, std = (np.array(v) for v in SIZE_STATS[category])
    return np.clip(mean + std * rng.standard_normal(3), mean - 2 * std, mean + 2 * std)


def plan_scene(rng: np.random.Generator, drive_side: int) -> ScenePlan:
    """Lay out a street and populate it for one 20 s scene."""
    ego_speed, ego_accel = _ego_speed_profile(rng)
    travel = ego_speed * SCENE_SECONDS + 0.5 * ego_accel * SCENE_SECONDS**2
    route = _random_route(rng, length=travel + 2 * ROUTE_MARGIN)
    section = CrossSection(
        lanes_per_direction=int(rng.choice([1, 2], p=[0.55, 0.45])),
        parking=bool(rng.random() < 0.75),
        drive_side=drive_side,
    )
    intersections = _intersections(rng, route, start=ROUTE_MARGIN - 60.0, stop=ROUTE_MARGIN + travel + 60.0)
    street = Street(route, section, intersections, center_line_yellow=drive_side > 0)
    ego_lane = int(rng.integers(section.lanes_per_direction))
    ego = EgoDrive(ROUTE_MARGIN, ego_speed, ego_accel, section.lane_center(ego_lane, +1))
    busyness = float(rng.uniform(0.35, 1.0))
    roadworks = section.parking and bool(rng.random() < 0.7)

    agents = AgentList.empty()
    blocked = _place_roadworks(agents, rng, street, ego) if roadworks else []
    _place_lane_traffic(agents, rng, street, ego, ego_lane, busyness)
    _place_parked_vehicles(agents, rng, street, busyness, blocked)
    _place_cyclists(agents, rng, street, busyness)
    _place_pedestrians(agents, rng, street, busyness)
    _place_crossing_traffic(agents, rng, street, busyness)
    buildings = _place_buildings(rng, street)
    return ScenePlan(street, ego, Agents.from_list(agents), buildings, busyness, roadworks)


def _ego_speed_profile(rng: np.random.Generator) -> tuple[float, float]:
    """Initial speed (m/s) and constant acceleration; ~15 % of scenes wait at a standstill."""
    if rng.random() < 0.15:
        return 0.0, 0.0
    speed = float(rng.uniform(2.5, 11.0))
    final = float(np.clip(speed + rng.normal(0.0, 2.0), 0.5, 13.0))
    return speed, (final - speed) / SCENE_SECONDS


def _random_route(rng: np.random.Generator, length: float) -> Route:
    """Straight stretches joined by gentle curves (radius 60-250 m)."""
    lengths, curvatures = [], []
    total = 0.0
    while total < length:
        straight = float(rng.uniform(60.0, 200.0))
        lengths.append(straight)
        curvatures.append(0.0)
        total += straight
        if rng.random() < 0.45:
            radius = float(rng.uniform(60.0, 250.0))
            angle = float(rng.uniform(0.2, 0.9))
            lengths.append(radius * angle)
            curvatures.append(float(rng.choice([-1.0, 1.0])) / radius)
            total += radius * angle
    origin = rng.uniform([300.0, 800.0], [2000.0, 1800.0])
    return Route(origin, float(rng.uniform(-np.pi, np.pi)), np.array(lengths), np.array(curvatures))


def _intersections(rng: np.random.Generator, route: Route, start: float, stop: float) -> tuple[Intersection, ...]:
    """Crossing streets on straight stretches, now and then (about one every 180 m)."""
    found = []
    s = start + float(rng.uniform(0.0, 120.0))
    while s < stop:
        segment = int(np.searchsorted(route.starts, s, side="right") - 1)
        on_straight = route.curvatures[segment] == 0.0 and (
            route.starts[segment] + 25.0 < s < route.starts[segment] + route.lengths[segment] - 25.0
        )
        if on_straight:
            xy, heading = route.pose(np.array([s]))
            found.append(Intersection(s, xy[0], float(heading[0] + np.pi / 2)))
        s += float(rng.uniform(120.0, 260.0))
    return tuple(found)


def _vehicle_category(rng: np.random.Generator, moving: bool) -> str:
    if moving:
        return str(rng.choice(["vehicle.car", "vehicle.truck", "vehicle.bus.rigid", "vehicle.motorcycle"],
                              p=[0.78, 0.16, 0.04, 0.02]))
    return str(rng.choice(["vehicle.car", "vehicle.truck", "vehicle.motorcycle"], p=[0.81, 0.17, 0.02]))


def _fill_line(rng: np.random.Generator, start: float, stop: float, gap_mean: float, first_gap: float = 0.0,
               min_gap: float = 2.5):
    """Positions along [start, stop): exponential gaps of mean ``gap_mean``, at least ``min_gap`` metres."""
    position = start + first_gap
    while position < stop:
        yield position
        position += max(float(rng.exponential(gap_mean)), min_gap)


def _place_lane_traffic(agents: AgentList, rng, street: Street, ego: EgoDrive, ego_lane: int, busyness: float) -> None:
    """Platoons in every driving lane; the ego's lane moves with the ego, 12 % of the
    other lanes are held up (stopped traffic)."""
    section = street.section
    ego_travel = ego.speed * SCENE_SECONDS + 0.5 * ego.accel * SCENE_SECONDS**2
    for direction in (+1, -1):
        for lane in range(section.lanes_per_direction):
            ego_lane_here = direction > 0 and lane == ego_lane
            if ego_lane_here:
                speed, accel = ego.speed, ego.accel
            else:
                speed = float(np.clip(rng.normal(6.6, 2.5), 0.0, 14.0)) if rng.random() > 0.12 else 0.0
                accel = 0.0
            travel = speed * SCENE_SECONDS + 0.5 * accel * SCENE_SECONDS**2
            # Cover what the ego sees during its drive, upstream far enough that traffic
            # flowing towards the ego's window keeps it populated until the end.
            lo = ego.s0 - ANNOTATION_RADIUS - 20.0 - (travel if direction > 0 else 0.0)
            hi = ego.s0 + ego_travel + ANNOTATION_RADIUS + 20.0 + (travel if direction < 0 else 0.0)
            position = lo
            while position < hi:
                category = _vehicle_category(rng, moving=speed > 0)
                size = sample_size(category, rng)
                position += size[1] / 2
                clear_of_ego = abs(position - ego.s0) > 5.0 + size[1] / 2
                if not ego_lane_here or clear_of_ego:
                    agents.add(category, size, p0=position, offset=section.lane_center(lane, direction),
                               speed=speed, accel=accel, direction=direction,
                               rider=category == "vehicle.motorcycle")
                position += size[1] / 2 + 2.5 + float(rng.exponential(32.0 / busyness))


def _place_parked_vehicles(agents: AgentList, rng, street: Street, busyness: float, blocked: list) -> None:
    section = street.section
    if not section.parking:
        return
    for side in (+1, -1):
        position = 0.0
        while position < street.route.length:
            category = _vehicle_category(rng, moving=False)
            size = sample_size(category, rng)
            size[0] = min(size[0], PARKING_WIDTH)  # what parks in a parking lane fits in it
            position += size[1] / 2
            free = not street.near_intersection(np.array([position]), margin=size[1] / 2 + 8.0)[0]
            free &= not any(lo - size[1] / 2 < position < hi + size[1] / 2 for s, lo, hi in blocked if s == side)
            if free and rng.random() < 0.3 * busyness + 0.1:
                # Parked with the flow of their side of the road, a few the other way round.
                with_flow = -side * section.drive_side
                direction = with_flow if rng.random() < 0.9 else -with_flow
                # Pulled in to the kerb, so wide vans and trucks stay clear of the bike lane.
                offset = side * (section.kerb - size[0] / 2 - float(rng.uniform(0.1, 0.3)))
                agents.add(category, size, p0=position, offset=offset, direction=direction, yaw_offset=float(rng.normal(0.0, 0.03)), parked=True)
            position += size[1] / 2 + 0.8 + float(rng.exponential(4.0))


def _place_cyclists(agents: AgentList, rng, street: Street, busyness: float) -> None:
    section = street.section
    for direction in (+1, -1):
        side = -section.drive_side * direction
        offset = side * (section.bike_lane_inner + 0.75)
        speed = float(np.clip(rng.normal(4.0, 1.0), 2.0, 7.0))
        for position in _fill_line(rng, 0.0, street.route.length, 2500.0 / busyness, float(rng.uniform(0, 800))):
            category = "vehicle.bicycle" if rng.random() < 0.8 else "vehicle.motorcycle"
            size = sample_size(category, rng)
            size[2] = max(size[2], 1.55)  # the box includes the rider
            agents.add(category, size, p0=position, offset=offset, speed=speed, direction=direction, rider=True)
    # Parked bicycles at the kerb, across the pavement edge.
    for side in (+1, -1):
        for position in _fill_line(rng, 0.0, street.route.length, 3500.0, float(rng.uniform(0, 1200))):
            size = sample_size("vehicle.bicycle", rng)
            size[2] = min(size[2], 1.15)
            agents.add("vehicle.bicycle", size, p0=position, offset=side * (section.kerb + 0.35),
                       yaw_offset=float(rng.choice([0.0, np.pi]) + rng.normal(0, 0.05)), parked=True)


def _place_pedestrians(agents: AgentList, rng, street: Street, busyness: float) -> None:
    """Walkers on three walking lines per pavement (1 m apart, each with its own direction
    and pace), and people standing by the building fronts."""
    section = street.section
    length = street.route.length
    for side in (+1, -1):
        for k, inset in enumerate((1.35, 2.35, 3.35)):
            direction = 1 if (k + (side > 0)) % 2 == 0 else -1
            speed = float(np.clip(rng.normal(1.35, 0.15), 0.9, 1.8))
            offset = side * (section.kerb + inset)
            for position in _fill_line(rng, 0.0, length, 140.0 / busyness, float(rng.uniform(0, 100))):
                category = "human.pedestrian.child" if rng.random() < 0.03 else "human.pedestrian.adult"
                agents.add(category, sample_size(category, rng), p0=position, offset=offset,
                           speed=speed, direction=direction)
        for position in _fill_line(rng, 0.0, length, 180.0 / busyness, float(rng.uniform(0, 100))):
            category = "human.pedestrian.adult"
            offset = side * (section.kerb + PAVEMENT_WIDTH - 0.2)
            agents.add(category, sample_size(category, rng), p0=position, offset=offset,
                       yaw_offset=float(rng.uniform(-np.pi, np.pi)))


def _place_crossing_traffic(agents: AgentList, rng, street: Street, busyness: float) -> None:
    """Queues waiting at the crossing streets' stop lines (the route has the green light)."""
    section = street.section
    for intersection in street.intersections:
        heading = intersection.heading
        for arm in (+1, -1):
            # Traffic approaching the junction on this arm drives towards it: direction -arm.
            lane_d = -section.drive_side * (-arm) * LANE_WIDTH / 2
            start = arm * (section.pavement_outer + 2.0)
            origin = intersection.center + lane_d * np.array([-np.sin(heading), np.cos(heading)])
            position = abs(start)
            for _ in range(int(rng.poisson(2.0 * busyness))):
                category = _vehicle_category(rng, moving=False)
                size = sample_size(category, rng)
                position += size[1] / 2
                agents.add(category, size, p0=arm * position, line=(origin[0], origin[1], heading),
                           direction=-arm)
                position += size[1] / 2 + float(rng.uniform(1.5, 4.0))


def _place_roadworks(agents: AgentList, rng, street: Street, ego: EgoDrive) -> list:
    """A closed stretch of the parking lane: barriers along its edge, a cone taper before
    it, workers inside. Returns (side, s_min, s_max) so no car is parked there."""
    section = street.section
    side = int(rng.choice([-1, 1]))
    start = ego.s0 + float(rng.uniform(-40.0, ego.speed * SCENE_SECONDS + 40.0))
    length = float(rng.uniform(15.0, 35.0))
    inner = section.parking_inner
    position = start
    while position < start + length:
        size = sample_size("movable_object.barrier", rng)
        # Barriers are annotated with their long side as the width: turn them across.
        agents.add("movable_object.barrier", size, p0=position + size[0] / 2, offset=side * (inner + 0.35),
                   yaw_offset=np.pi / 2)
        position += size[0] + float(rng.uniform(0.05, 0.4))
    n_cones = int(rng.integers(4, 10))
    for k in range(n_cones):
        size = sample_size("movable_object.trafficcone", rng)
        across = inner + 0.35 + (PARKING_WIDTH - 0.7) * (k + 1) / n_cones
        agents.add("movable_object.trafficcone", size, p0=start - 2.5 * (k + 1), offset=side * across)
    n_workers = int(rng.integers(0, 3))
    for k in range(n_workers):
        category = "human.pedestrian.construction_worker"
        spread = start + length * (k + 1) / (n_workers + 1)  # apart, at least 5 m
        agents.add(category, sample_size(category, rng), p0=spread + float(rng.uniform(-1.0, 1.0)),
                   offset=side * (inner + float(rng.uniform(1.1, 1.8))), yaw_offset=float(rng.uniform(-np.pi, np.pi)))
    return [(side, start - 2.5 * n_cones - 5.0, start + length)]


def _place_buildings(rng: np.random.Generator, street: Street) -> tuple[Building, ...]:
    """Blocks along both sides, set back from the pavement, none across a crossing street."""
    buildings = []
    route = street.route
    for side in (+1, -1):
        position = 0.0
        while position < route.length:
            frontage = float(rng.uniform(8.0, 30.0))
            depth = float(rng.uniform(8.0, 16.0))
            center_s = position + frontage / 2
            if not street.near_intersection(np.array([center_s]), margin=frontage / 2 + PAVEMENT_WIDTH + 2.0)[0]:
                setback = float(rng.uniform(0.5, 4.0))
                d = side * (street.section.pavement_outer + setback + depth / 2)
                xy, heading = route.pose(np.array([center_s]), d)
                height = float(rng.choice([rng.uniform(4.0, 9.0), rng.uniform(9.0, 30.0)]))
                buildings.append(Building(xy[0], float(heading[0]), np.array([depth, frontage, height])))
            position += frontage + float(rng.exponential(3.0))
    return tuple(buildings)
