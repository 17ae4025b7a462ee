"""Traffic of one synthetic scene: the ego's drive and every other road user, as paths.

An agent moves along a *path*: the route with a lateral offset (lanes, bike lanes,
pavements, parking lanes, car-park bays) or a straight line (a crossing street). Its position
on the path at time ``t`` is ``clip(p0 + direction * (v t + a t^2 / 2), p_min, p_max)``, and
a lane change or parking manoeuvre moves the offset by a smoothstep (``manoeuvres.py``), so
speed and heading are consistent between keyframes by construction, and agents that share a
lane share its speed, which keeps them from driving into one another. Nearly half of
the routes turn at a T or 4-way junction (``TURN_SHARE``), where the ego turns too.

Places: streets of one or two lanes each way and arterials of three with a planted median;
crossings and side streets where the route goes straight on; T and 4-way junctions where it
turns; car parks; driveways. At a crossing or side street the crossing street's arms either
wait at the stop line or flow: their cars drive across the route or turn onto it, and cars
of the route's lanes turn off into the crossing street, each on a path of its own
(``junctions.py``: lane, 90-degree fillet, lane). Cars wait in driveways and pull out. A road
user that would meet anyone on its way through a junction arrives later, or is left out
(``_drop_junction_conflicts``), so no two road users ever overlap.

Class mix and density target nuScenes' published figures (objects per trainval keyframe, the
mini's vehicle attributes, moving-object and ego speeds; docs/synthetic_world.md#nuscenes-figures).
``sianms info`` prints what a generated dataset actually holds.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from typing import Sequence

import numpy as np

from sianms_cli.synth.junctions import ARM_LENGTH, turn_off_route, turn_onto_route, turn_radius
from sianms_cli.synth.manoeuvres import (
    CLEARANCE,
    EGO_LANE_CHANGE_SHARE,
    EGO_SIZE,
    closest_approach,
    plan_manoeuvres,
    without,
)
from sianms_cli.synth.parking import bay_poses, choose_car_parks
from sianms_cli.synth.road import (
    AISLE_WIDTH,
    BAY_DEPTH,
    BAY_START,
    LANE_WIDTH,
    PARKING_WIDTH,
    PAVEMENT_WIDTH,
    ROW_PITCH,
    CrossSection,
    Intersection,
    Route,
    Street,
)

SCENE_SECONDS = 20.0
KEYFRAME_HZ = 2.0
ANNOTATION_RADIUS = 80.0  # metres from the ego: nuScenes car annotations reach ~80 m
ROUTE_MARGIN = 160.0  # route length before and after the ego's drive
TURN_SHARE = 0.45
"""Scenes whose ego turns at a junction. 73.9 % of nuScenes key frames are go-straight (Li et
al. arXiv 2312.03031), read as the planning benchmark's command rule, which `sianms info` applies;
a later-found third-party count by that rule gives 86.7 % on val (docs/synthetic_world.md#still-short),
and this share was left as set. A turning scene commands a turn in a third of its key frames (the
approach and the turn itself; 34 % on seed 11's 40 scenes), the other scenes in 4 %
(lane changes, the tighter curves), so even this share leaves the go-straight figure near 82 %;
was 0.25, read as a share of scenes, which left it at 85 %. Not higher (our choice): objects seen
before the corner and hidden by its buildings after it raise the share of annotations without a
LiDAR point (0.55, with more roadworks, put it at 19.5 % on the 40-scene set, above nuScenes'
18.7 %)."""
TURN_RADIUS = (12.0, 20.0)  # metres, centreline radius of a turn at a town junction
TURN_ROAD_SPEED = 8.0  # m/s: the fastest traffic on a street with a turn
ROADWORKS_SHARE = 0.65
"""Streets with a parking lane that have roadworks: 0.75 x 0.65 = 49 % of the scenes, fewer once
those without room between junctions drop out. nuScenes over-samples construction sites
(nuScenes paper §2) and holds 4.45 barriers and 2.87 cones per trainval keyframe
(docs/synthetic_world.md#nuscenes-figures); the share is set against those figures. A set's
figures swing with which of its scenes get a site (seed 11's 40 scenes: 2.8 / 1.3; seed 2026's
10: 6.2 / 3.7); more sites raised the share of
annotations without a LiDAR point above nuScenes' 18.7 % (a far barrier or cone is mostly
annotated without a point), so the share stopped at 0.5; once a far sighting took two points
(generate.SINGLE_POINT_SIGHTING_RANGE) the far barriers and cones went and 0.65 restored the
near ones (120 scenes of seed 13: 5.14 barriers and 2.32 cones per keyframe)."""
ROADWORKS_BOTH_SIDES = 0.3
"""Roadworks sites that close the parking lanes on both sides of the street (utility trenches
and building sites facing each other; our choice, set with ROADWORKS_SHARE against the barrier
and cone figures of docs/synthetic_world.md#nuscenes-figures)."""
ROADWORKS_LENGTH = (80.0, 160.0)
"""Metres of closed parking lane between the tapers (our choice). Shorter sites (40-90 m) in
more scenes were tried and put more barriers beyond 30 m and more of them without a LiDAR point,
not fewer: the far barriers are those of sites the ego sees from afar."""
ROADWORKS_TRIES = 3
"""Places near the ego's drive tried for a site before the street goes without: a site and
its tapers need 70 m or more between two junctions (our choice)."""
TAPER_CONES = (10, 23)
"""Cones per taper (integers low..high-1), 2.5 m apart: 15-30 m tapers, between the shoulder
taper (L/3) and the merging taper (L = W S^2 / 60 ft, 36 m for a 2.4 m lane at 30 mph) of the
US MUTCD (Table 6C-3/6C-4) for closing a parking lane; 6-12 while a single far point was a
sighting, 10-22 since far cones need two points (cones lost 40 % of their annotations, all far)."""
CONSTRUCTION_VEHICLE_SHARE = 0.6
"""Taper ends with a construction vehicle parked beyond them: trainval holds 0.43 construction
vehicles per keyframe (14,671 / 34,149) and the nuScenes paper's supplement shows they rarely
move (supplement Fig. 8), so they stand at the sites; the share is set against that figure (0.75 before
sites grew more common with ROADWORKS_SHARE)."""

KERB_PARKED_CATEGORIES = ("vehicle.car", "vehicle.truck", "vehicle.motorcycle", "vehicle.trailer",
                          "vehicle.construction")
KERB_PARKED_SHARES = (0.678, 0.128, 0.039, 0.114, 0.041)
"""What parks in a parking lane. Trailers left without their tractor and construction plant
between jobs stand at the kerb, as the nuScenes supplement shows both classes mostly parked
(Fig. 8). Each share is set against trainval's objects per keyframe (docs/synthetic_world.md#nuscenes-figures: trucks
2.59, trailers 0.73, construction vehicles 0.43, motorcycles 0.37) less what moves, stops or
works at roadworks: the kerb-parked count a category still needs, over what a unit share parked
on seed 13's 120 scenes once the parking lanes filled up (``KERB_GAP``, ``PARKED_SHARE``). The
shares set for the sparse kerb before, (0.44, 0.15, 0.07, 0.25, 0.09), put 1.39 trailers per
keyframe on seed 11's 40 scenes once 0.55 x (busyness + 0.3) of the dense slots were taken (0.41
on the sparse kerb)."""

# (w, l, h) mean and std per category, nuScenes trainval (list_categories(); docs/synthetic_world.md#nuscenes-figures).
SIZE_STATS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "vehicle.car": ((1.95, 4.62, 1.73), (0.19, 0.46, 0.24)),
    "vehicle.truck": ((2.51, 6.93, 2.84), (0.45, 2.17, 0.84)),
    "vehicle.bus.rigid": ((2.93, 11.23, 3.47), (0.33, 2.07, 0.52)),
    "vehicle.trailer": ((2.90, 12.29, 3.87), (0.53, 4.52, 0.75)),
    "vehicle.construction": ((2.85, 6.37, 3.19), (1.06, 3.13, 1.02)),
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
    "vehicle.trailer": "trailer",
    "vehicle.construction": "construction",
    "vehicle.motorcycle": "motorcycle",
    "vehicle.bicycle": "bicycle",
    "human.pedestrian.adult": "pedestrian",
    "human.pedestrian.child": "pedestrian",
    "human.pedestrian.construction_worker": "pedestrian",
    "movable_object.barrier": "barrier",
    "movable_object.trafficcone": "traffic_cone",
}

LANES_PER_DIRECTION_SHARES = (0.45, 0.35, 0.20)
"""Streets of 1, 2 and 3 lanes each way; 3-lane streets are arterials with a median (Seaport
Boulevard and Congress Street in Boston Seaport, the 3-lane dual carriageways of One North
and Queenstown). Our estimate of the nuScenes routes' mix, no published figure."""
MEDIAN_WIDTH = (2.0, 6.0)
"""Metres of planted median on an arterial: wide enough for planting, no wider than a turn
pocket plus its kerbs (our estimate; no published distribution for the nuScenes cities)."""
JUNCTION_SPACING = (80.0, 200.0)
"""Metres between junctions along the route: city blocks of 80-200 m (Boston Seaport's blocks
are ~100-150 m, Singapore's estates have side roads every 100-200 m; our estimate from
maps, no published figure)."""
SIDE_STREET_SHARE = 0.5
"""Junctions along the route that are side streets (T junctions the route goes straight past)
rather than crossings: three-way junctions are about as common as four-way ones in the
street networks of US and European cities (our estimate after street-network studies; no
figure for the nuScenes routes)."""
DRIVEWAYS_PER_SCENE = 1.0
"""Poisson mean of driveways along the ego's drive with a car waiting to pull out (our
estimate: a few driveways per block on both sides, most of them empty at any moment)."""
FLOWING_ARM_SHARE = 0.5
"""Arms of a straight-across junction whose traffic drives through (the others wait at the
stop line): a signal gives the crossing street green about half of each cycle, and nuScenes
junction scenes show both (our estimate; no published figure)."""
TURN_IN_SHARE = 0.2
TURN_OFF_SHARE = 0.2
"""Vehicles reaching a junction that turn (left and right together): our estimate, half left
and half right; nuScenes publishes no turning shares for its routes."""
JUNCTION_CHECK_STEP = 0.05  # s: 1.1 m at the largest crossing speed difference (22 m/s)
GIVE_WAY_TRIES = 3  # later arrivals tried before a junction road user is left out
# Densities (mean gaps in metres, times 1 / busyness; the parked share of kerb slots), set so
# that a 40-scene set holds trainval's objects per keyframe (docs/synthetic_world.md#nuscenes-figures: cars 14.4,
# pedestrians 6.4, trucks 2.6, buses 0.48, motorcycles 0.37, bicycles 0.35) once only the
# keyframes between an object's first and last LiDAR sighting are annotated
# (generate._annotation_records), and so that its vehicles are parked / moving / stopped as
# nuScenes' (52.3 / 30.4 / 17.3 % on mini; no trainval table); the vehicle mixes are in
# _vehicle_category. Until the kerb filled up, parking lanes held a vehicle every ~36 m
# (0.27 x (busyness + 0.3) of slots 0.8 m + exp(4 m) apart) and 12 % of lanes were held up,
# which left seed 11's 40 scenes at 34.1 % parked, 53.6 % moving and 12.3 % stopped.
LANE_GAP = 30.0  # a lane's mean gap per vehicle, beyond 2.5 m (in platoons: FOLLOWING_HEADWAY)
HELD_UP_LANE_SHARE = 0.38
"""Lanes other than the ego's whose traffic stands (queued at a light, in a jam)."""
QUEUE_VEHICLES = 6.0
"""Mean vehicles in a platoon (geometric), standing or moving: a red phase of ~35 s at ~600
vehicles per hour and lane queues six (our estimate of an urban signal; the 1,900 vehicles per
hour that discharge them at green is the Highway Capacity Manual's base saturation flow), and
the queue leaves the signal as a platoon."""
STANDSTILL_GAP = (2.0, 1.0)
FOLLOWING_HEADWAY = 1.5
"""A vehicle follows the one ahead in its platoon at 2 m + exp(1 m) + 1.5 s x speed: the
intelligent driver model's standstill distance s0 = 2 m and time gap T = 1.5 s (Treiber,
Hennecke and Helbing, Phys. Rev. E 62, 2000), so a standing queue closes up nose to tail.
Platoons are as far apart as keeps a lane's mean spacing per vehicle that of evenly spread
traffic (2.5 m + exp(``LANE_GAP`` / busyness)), so platoons change where vehicles are, not how
many there are; before, each vehicle drove or stood on its own, ~40 m from the next."""
PARKED_SHARE = 0.42  # of kerb-side slots, times (busyness + 0.3)
KERB_GAP = (0.8, 1.5)
"""Metres between the slots of a parking lane: at least 0.8 plus an exponential of mean 1.5,
as drivers leave a metre or two to pull out of a parallel bay (our estimate; on a busy
street's kerb the cars stand nearly end to end, and one parked car hides part of the next)."""
RIDER_GAP = 780.0  # between riders in a bike lane
PARKED_BICYCLE_GAP = 630.0  # between bicycles parked at one kerb (not times 1 / busyness)
# The first rider and the first parked bicycle of a line start within one mean gap of the route's
# start (a renewal process seen from a random point). Before, they started within a fixed 1,800 /
# 2,400 m on routes of ~450 m, which held bicycles at 0.22 per keyframe whatever the gaps said;
# trainval has 0.35, 59 % of them without a rider (mini attribute shares).
WALKER_GAP = 68.0  # between walking parties (a walker alone or a group) on one pavement stream
STANDING_GAP = 95.0  # between people standing at the back of a pavement
MOVING_SPEED = 0.2  # m/s: below this a road user counts as standing still
DEPARTURE_STOP = 120.0  # metres from a junction where cars leaving along a crossing street stop
WALKER_QUEUE_SPACING = 1.2  # metres between walkers waiting at a junction (2-sigma body length + gap)
PARTY_SIZES = (1, 2, 3)
PARTY_SIZE_SHARES = (0.6, 0.3, 0.1)
"""Walking parties on a pavement: 60 % of the walkers walk in a group, three groups in four
pairs. Up to 70 % of the people of a crowded shopping street walk in groups, most of them
pairs (Moussaid et al., PLoS ONE 5(4) e10047, 2010); the 60 % and the split between pairs and
triads are our estimates for city pavements. A party holds 1.5 walkers on average, so
``WALKER_GAP`` between parties on two streams per pavement keeps the density that 68 m
between single walkers on three lines had."""
ABREAST_SPACING = 1.0
"""Metres between group members walking side by side: the spacing of the pavement's walking
lines. Groups walk abreast at low density, a line across the walking direction; triads bend
it into a V, the middle walker slightly behind (Moussaid et al. 2010, whose model keeps 0.8 m
between neighbours; Zanlungo et al., PLoS ONE 14(12) e0225704, 2019)."""
V_SETBACK = 0.8  # metres a triad's middle walker keeps behind the two beside it
WALKING_LINES = (1.35, 1.35 + ABREAST_SPACING, 1.35 + 2 * ABREAST_SPACING)
"""Insets (m from the kerb) of a pavement's walking lines: the first keeps every walker's box
clear of the kerb strip (clutter.KERB_STRIP)."""
AISLE_WALKER_GAP = 48.0
"""Mean gap between people walking along one line of a car park's aisle (two lines per aisle,
one each way): people walk to and from their cars there, 10-30 m from the road, where the
cameras' views overlap (our estimate; nuScenes publishes no pedestrian positions). 30 m put
pedestrians at 8.1 per keyframe on seed 11's 40 scenes against trainval's 6.45."""
BAYS_TAKEN = (0.15, 0.3)
"""Share of a car park's bays taken: 0.15 + 0.3 x busyness (15-45 %). Set against trainval's
14.45 cars per keyframe once car parks had up to three rows: the single row's 25-65 % then put
16.4 cars per keyframe on seed 11's 40 scenes and 19.9 on the mini of seed 2026."""


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
    shift: list  # (lateral change d metres, start s, duration s) of a lane change, d = 0 for none
    path: list  # a Route of its own (turning through a junction), None for the route or a line

    @classmethod
    def empty(cls) -> "AgentList":
        return cls(*([] for _ in range(14)))

    def add(self, category, size, *, p0, offset=0.0, line=None, speed=0.0, accel=0.0, direction=1,
            p_range=(-np.inf, np.inf), yaw_offset=0.0, parked=False, rider=False, shift=(0.0, 0.0, 1.0),
            path=None) -> None:
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
        self.shift.append(shift)
        self.path.append(path)


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
    shift: np.ndarray  # (N,3) lane change: lateral change d (m, 0 for none), start time, duration (s)
    path: np.ndarray  # (N,) object: a Route of the agent's own (offset 0, travelled forwards), or None

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
            shift=np.array(agents.shift, dtype=float).reshape(n, 3),
            path=_object_array(agents.path),
        )

    def __len__(self) -> int:
        return len(self.category)

    @cached_property
    def _own_path_rows(self) -> np.ndarray:
        """Rows of the agents on a path of their own (computed once per instance)."""
        return np.flatnonzero([path is not None for path in self.path])

    def path_position(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Path coordinate (N,) and speed along the path (N,) m/s at time ``t`` seconds."""
        travelled = self.speed * t + 0.5 * self.accel * t * t
        raw = self.p0 + self.direction * travelled
        clipped = np.clip(raw, self.p_range[:, 0], self.p_range[:, 1])
        speed = np.where(clipped == raw, np.abs(self.speed + self.accel * t), 0.0)
        return clipped, speed

    def pose(self, route: Route, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Box centres (N,3) global, yaw (N,) and ground speed (N,) m/s at time ``t``.

        On a curve, a path at offset ``d`` is a circle of radius ``1/k - d``, so the speed
        along it is the speed along the centreline times ``|1 - k d|``. During a lane change
        the offset also moves sideways, and the yaw turns towards the direction of travel.
        """
        p, speed = self.path_position(t)
        d, d_rate = lateral_offset(self.offset, self.shift, t)
        xy_route, heading_route = route.pose(p, d)
        along = speed * np.abs(1.0 - route.curvature_at(p) * d)
        steer = self.direction * np.arctan2(d_rate, along)
        speed = np.where(self.on_line, speed, np.hypot(along, d_rate))
        heading_line = self.line[:, 2]
        xy_line = self.line[:, :2] + p[:, None] * np.stack([np.cos(heading_line), np.sin(heading_line)], axis=1)
        xy = np.where(self.on_line[:, None], xy_line, xy_route)
        heading = np.where(self.on_line, heading_line, heading_route + steer)
        for k in self._own_path_rows:
            # Turning through a junction on a path of its own: a centreline at offset 0
            # (offset 0 and no lane change, so its speed along the path is already right).
            xy[k, 0], xy[k, 1], heading[k] = self.path[k].point(float(p[k]))
        yaw = heading + np.where(self.direction < 0, np.pi, 0.0) + self.yaw_offset
        yaw = np.mod(yaw + np.pi, 2 * np.pi) - np.pi
        center = np.column_stack([xy, self.size[:, 2] / 2])
        return center, yaw, speed

    def attributes(self, speed: np.ndarray) -> np.ndarray:
        """nuScenes attribute name (N,) ("" for none) for ground speeds (N,)."""
        moving = speed > MOVING_SPEED
        names = np.full(len(self), "", dtype=object)
        category = self.category
        vehicle = np.isin(category, ["vehicle.car", "vehicle.truck", "vehicle.bus.rigid", "vehicle.trailer",
                                     "vehicle.construction"])
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
    """The ego vehicle's motion along its lane: s(t) = s0 + v t + a t^2 / 2, and a lane
    change ``shift`` = (lateral change d, start, duration) as for :class:`Agents`."""

    s0: float
    speed: float
    accel: float
    offset: float
    shift: tuple[float, float, float] = (0.0, 0.0, 1.0)

    def s(self, t: float | np.ndarray) -> np.ndarray:
        return self.s0 + self.speed * np.asarray(t) + 0.5 * self.accel * np.asarray(t) ** 2

    def pose(self, route: Route, t: float) -> tuple[np.ndarray, float]:
        """Ego xy (2,) and yaw at time ``t``."""
        xy, yaw = self.track(route, np.array([t], dtype=float))
        return xy[0], float(yaw[0])

    def track(self, route: Route, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ego xy (T,2) and yaw (T,) at ``times`` (T,): the yaw turns towards the direction of
        travel while the ego changes lane."""
        s = self.s(times)
        shift = np.broadcast_to(np.array(self.shift, dtype=float), (len(times), 3))
        d, d_rate = lateral_offset(np.full(len(times), self.offset), shift, times)
        xy, heading = route.pose(s, d)
        along = np.abs(self.speed + self.accel * times) * np.abs(1.0 - route.curvature_at(s) * d)
        return xy, heading + np.arctan2(d_rate, along)


def _object_array(values: list) -> np.ndarray:
    """A 1-D object array of ``values`` (numpy would build a 2-D array of sequences)."""
    array = np.empty(len(values), dtype=object)
    array[:] = values
    return array


def lateral_offset(offset: np.ndarray, shift: np.ndarray, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Offset d (N,) and its rate (N,) m/s at time ``t`` (scalar or (N,)) of paths at ``offset`` (N,) with lane
    changes ``shift`` (N,3): a smoothstep from ``offset`` to ``offset + change`` over the
    duration, so the sideways speed starts and ends at zero (a change of lane or pulling in
    or out of a parking space takes 3-6 s)."""
    change, start, duration = shift[:, 0], shift[:, 1], shift[:, 2]
    u = np.clip((t - start) / duration, 0.0, 1.0)
    return offset + change * u * u * (3.0 - 2.0 * u), change * 6.0 * u * (1.0 - u) / duration


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
    turn = bool(rng.random() < TURN_SHARE)
    ego_speed, ego_accel = _ego_speed_profile(rng, turn)
    travel = ego_speed * SCENE_SECONDS + 0.5 * ego_accel * SCENE_SECONDS**2
    lanes = int(rng.choice([1, 2, 3], p=LANES_PER_DIRECTION_SHARES))
    arterial = lanes == 3 and not turn  # the ego turns at town junctions, not off an arterial
    section = CrossSection(
        lanes_per_direction=lanes if arterial or lanes < 3 else 2,
        parking=bool(rng.random() < 0.75),
        drive_side=drive_side,
        median=float(rng.uniform(*MEDIAN_WIDTH)) if arterial else 0.0,
    )
    if turn:
        route, junctions = _turning_route(rng, travel)
        stop = junctions[0].s - junctions[0].half_span - 60.0  # no crossing street meets the junction's
    else:
        route, junctions = _random_route(rng, length=travel + 2 * ROUTE_MARGIN), ()
        stop = ROUTE_MARGIN + travel + 60.0
    intersections = junctions + _intersections(rng, route, start=ROUTE_MARGIN - 60.0, stop=stop)
    street = Street(route, section, intersections, center_line_yellow=drive_side > 0)
    ego_lane = int(rng.integers(section.lanes_per_direction))
    ego = EgoDrive(ROUTE_MARGIN, ego_speed, ego_accel, section.lane_center(ego_lane, +1))
    street = replace(street, car_parks=choose_car_parks(rng, street, ego.s0, ego.s0 + travel))
    busyness = float(rng.uniform(0.35, 1.0))
    roadworks = section.parking and bool(rng.random() < ROADWORKS_SHARE)

    agents = AgentList.empty()
    works = _place_roadworks(agents, rng, street, ego) if roadworks else []
    crossing: list[int] = []
    driveways = _place_driveways(agents, rng, street, ego, crossing)
    blocked = works + driveways
    _place_lane_traffic(agents, rng, street, ego, ego_lane, busyness, max_speed=TURN_ROAD_SPEED if turn else 14.0)
    _place_parked_vehicles(agents, rng, street, busyness, blocked)
    _place_car_park_cars(agents, rng, street, busyness)
    _place_cyclists(agents, rng, street, busyness)
    _place_pedestrians(agents, rng, street, busyness)
    _place_car_park_walkers(agents, rng, street, busyness)
    crossing += _place_crossing_traffic(agents, rng, street, busyness)
    _turn_off_route(agents, rng, street, crossing)
    buildings = _place_buildings(rng, street, driveways)
    ego_lane_change = (not turn and section.lanes_per_direction >= 2 and ego_speed > 0
                       and bool(rng.random() < EGO_LANE_CHANGE_SHARE))
    placed = _drop_junction_conflicts(Agents.from_list(agents), crossing, street, ego, rng)
    ego, moving = plan_manoeuvres(rng, street, ego, placed, ego_lane_change, SCENE_SECONDS)
    return ScenePlan(street, ego, moving, buildings, busyness, bool(works))


def _ego_speed_profile(rng: np.random.Generator, turn: bool) -> tuple[float, float]:
    """Initial speed (m/s) and constant acceleration; ~15 % of the scenes that do not turn
    wait at a standstill. A turning ego keeps to 2-8 m/s, the speed of a 12-20 m radius
    turn in town (lateral acceleration at most ~3 m/s^2)."""
    if turn:
        speed = float(rng.uniform(3.0, 7.5))
        final = float(np.clip(speed + rng.normal(0.0, 1.5), 2.0, 8.0))
        return speed, (final - speed) / SCENE_SECONDS
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


def _turning_route(rng: np.random.Generator, travel: float) -> tuple[Route, tuple[Intersection, ...]]:
    """A straight road, a 90-degree turn of radius 12-20 m at a junction, a straight road.

    The middle of the turn falls 20-80 % of the way through the ego's drive, so the ego
    is seen approaching, turning and leaving. The junction is a T (the crossing street runs
    along the outgoing road, its other arm behind) or a 4-way (the incoming road also goes on
    beyond it), half and half.
    """
    radius = float(rng.uniform(*TURN_RADIUS))
    sign = float(rng.choice([-1.0, 1.0]))
    arc = radius * np.pi / 2
    middle = ROUTE_MARGIN + float(rng.uniform(0.2, 0.8)) * travel
    before = middle - arc / 2
    after = travel + 2 * ROUTE_MARGIN - before - arc
    origin = rng.uniform([300.0, 800.0], [2000.0, 1800.0])
    heading_in = float(rng.uniform(-np.pi, np.pi))
    route = Route(origin, heading_in, np.array([before, arc, after]), np.array([0.0, sign / radius, 0.0]))
    turn_start, _ = route.pose(np.array([before]))
    corner = turn_start[0] + radius * np.array([np.cos(heading_in), np.sin(heading_in)])
    half_span = arc / 2 + 2.0
    junctions = [Intersection(middle, corner, heading_in + sign * np.pi / 2, arms=(-1,), half_span=half_span)]
    if rng.random() < 0.5:
        junctions.append(Intersection(middle, corner, heading_in, arms=(1,), half_span=half_span))
    return route, tuple(junctions)


def _intersections(rng: np.random.Generator, route: Route, start: float, stop: float) -> tuple[Intersection, ...]:
    """Crossing streets on straight stretches, now and then (about one every 140 m); a share
    ``SIDE_STREET_SHARE`` of them are side streets on one side of the route only."""
    found = []
    s = start + float(rng.uniform(0.0, 120.0))
    while s < stop:
        segment = int(np.searchsorted(route.starts, s, side="right") - 1)
        on_straight = route.curvatures[segment] == 0.0 and (
            route.starts[segment] + 25.0 < s < route.starts[segment] + route.lengths[segment] - 25.0
        )
        side_street = bool(rng.random() < SIDE_STREET_SHARE)
        arms = (int(rng.choice([-1, 1])),) if side_street else (-1, 1)
        if on_straight:
            xy, heading = route.pose(np.array([s]))
            found.append(Intersection(s, xy[0], float(heading[0] + np.pi / 2), arms=arms, side_street=side_street))
        s += float(rng.uniform(*JUNCTION_SPACING))
    return tuple(found)


def _vehicle_category(rng: np.random.Generator, moving: bool, parked: bool = False) -> str:
    """A category for a vehicle in traffic, at the kerb or stopped (in driveways, queues). Buses
    are 8 % of moving traffic (5 % before the lanes thinned out for the parked cars, which left
    0.29 buses per keyframe on seed 13's 120 scenes against trainval's 0.48)."""
    if moving:
        return str(rng.choice(["vehicle.car", "vehicle.truck", "vehicle.bus.rigid", "vehicle.motorcycle"],
                              p=[0.73, 0.16, 0.08, 0.03]))
    if parked:
        return str(rng.choice(KERB_PARKED_CATEGORIES, p=KERB_PARKED_SHARES))
    return str(rng.choice(["vehicle.car", "vehicle.truck", "vehicle.motorcycle"], p=[0.803, 0.17, 0.027]))


def _fill_line(rng: np.random.Generator, start: float, stop: float, gap_mean: float, first_gap: float = 0.0,
               min_gap: float = 2.5):
    """Positions along [start, stop): exponential gaps of mean ``gap_mean``, at least ``min_gap`` metres."""
    position = start + first_gap
    while position < stop:
        yield position
        position += max(float(rng.exponential(gap_mean)), min_gap)


def _place_lane_traffic(agents: AgentList, rng, street: Street, ego: EgoDrive, ego_lane: int, busyness: float,
                        max_speed: float) -> None:
    """Platoons in every driving lane; the ego's lane moves with the ego, ``HELD_UP_LANE_SHARE``
    of the other lanes are held up (stopped traffic), none is faster than ``max_speed`` m/s."""
    section = street.section
    ego_travel = ego.speed * SCENE_SECONDS + 0.5 * ego.accel * SCENE_SECONDS**2
    for direction in (+1, -1):
        for lane in range(section.lanes_per_direction):
            ego_lane_here = direction > 0 and lane == ego_lane
            if ego_lane_here:
                speed, accel = ego.speed, ego.accel
            else:
                held_up = rng.random() < HELD_UP_LANE_SHARE
                speed = 0.0 if held_up else float(np.clip(rng.normal(6.6, 2.5), 0.0, max_speed))
                accel = 0.0
            travel = speed * SCENE_SECONDS + 0.5 * accel * SCENE_SECONDS**2
            # Cover what the ego sees during its drive, upstream far enough that traffic
            # flowing towards the ego's window keeps it populated until the end.
            lo = ego.s0 - ANNOTATION_RADIUS - 20.0 - (travel if direction > 0 else 0.0)
            hi = ego.s0 + ego_travel + ANNOTATION_RADIUS + 20.0 + (travel if direction < 0 else 0.0)
            queued = speed == 0 and not ego_lane_here
            # Platoons start well before lo, so that where they are is random.
            position = lo - 2.0 * QUEUE_VEHICLES * (LANE_GAP / busyness + 10.0)
            while position < hi:
                category = _vehicle_category(rng, moving=speed > 0)
                size = sample_size(category, rng)
                position += size[1] / 2
                # The ego drives in its lane's platoon: who follows it or leads it keeps the platoon's gap.
                clear_of_ego = abs(position - ego.s0) > EGO_SIZE[1] / 2 + size[1] / 2 + _following_gap(speed)
                # Queues stand short of a junction and leave its box clear for the crossing traffic.
                clear_of_junctions = not (queued and street.near_intersection(np.array([position]),
                                                                             margin=size[1] / 2 + 2.0)[0])
                if position >= lo and (not ego_lane_here or clear_of_ego) and clear_of_junctions:
                    agents.add(category, size, p0=position, offset=section.lane_center(lane, direction),
                               speed=speed, accel=accel, direction=direction,
                               rider=category == "vehicle.motorcycle")
                position += size[1] / 2 + _platoon_gap(rng, busyness, speed)


def _following_gap(speed: float) -> float:
    """Least metres between a vehicle and the one it follows at ``speed`` m/s (FOLLOWING_HEADWAY)."""
    return STANDSTILL_GAP[0] + FOLLOWING_HEADWAY * speed


def _platoon_gap(rng: np.random.Generator, busyness: float, speed: float) -> float:
    """Metres behind a vehicle of a lane moving at ``speed`` m/s: the following gap inside a
    platoon, or, once in ``QUEUE_VEHICLES`` on average, the road up to the next platoon, whose
    mean makes the lane's mean gap per vehicle 2.5 m + ``LANE_GAP`` / busyness (see
    ``FOLLOWING_HEADWAY``)."""
    following = _following_gap(speed)
    if rng.random() >= 1.0 / QUEUE_VEHICLES:
        return following + float(rng.exponential(STANDSTILL_GAP[1]))
    mean_following = following + STANDSTILL_GAP[1]
    free = QUEUE_VEHICLES * max(2.5 + LANE_GAP / busyness - mean_following, 0.0)
    return mean_following + float(rng.exponential(free))


def _place_parked_vehicles(agents: AgentList, rng, street: Street, busyness: float, blocked: list) -> None:
    section = street.section
    if not section.parking:
        return
    for side in (+1, -1):
        position = 0.0
        while position < street.route.length:
            category = _vehicle_category(rng, moving=False, parked=True)
            size = sample_size(category, rng)
            size[0] = min(size[0], PARKING_WIDTH)  # what parks in a parking lane fits in it
            position += size[1] / 2
            free = not street.near_intersection(np.array([position]), margin=size[1] / 2 + 8.0)[0]
            free &= not any(lo - size[1] / 2 < position < hi + size[1] / 2 for s, lo, hi in blocked if s == side)
            if free and rng.random() < PARKED_SHARE * (busyness + 0.3):
                # Parked with the flow of their side of the road, a few the other way round.
                with_flow = -side * section.drive_side
                direction = with_flow if rng.random() < 0.9 else -with_flow
                # Pulled in to the kerb, so wide vans and trucks stay clear of the bike lane.
                offset = side * (section.kerb - size[0] / 2 - float(rng.uniform(0.1, 0.3)))
                agents.add(category, size, p0=position, offset=offset, direction=direction,
                           yaw_offset=float(rng.normal(0.0, 0.03)), parked=True)
            position += size[1] / 2 + KERB_GAP[0] + float(rng.exponential(KERB_GAP[1]))


def _turn_spans(street: Street) -> np.ndarray:
    """(K,2) route arc-length intervals of the junctions where the route turns: the offset
    paths of pavements and parking lanes fold over inside such a tight turn, so nobody
    walks, waits or parks on them there."""
    spans = [(i.s - i.half_span - 4.0, i.s + i.half_span + 4.0) for i in street.intersections if not i.through]
    return np.array(spans, dtype=float).reshape(-1, 2)


def _in_spans(position: float, spans: np.ndarray, margin: float = 0.0) -> bool:
    return bool(np.any((position > spans[:, 0] - margin) & (position < spans[:, 1] + margin)))


def _walk_range(position: float, direction: int, spans: np.ndarray) -> tuple[float, float]:
    """Path range (p_min, p_max) of a walker that stops at the edge of the first turning
    junction ahead of it (waiting to cross) instead of walking into it."""
    ahead = spans[:, 0] - position if direction > 0 else position - spans[:, 1]
    if not np.any(ahead > 0):
        return (-np.inf, np.inf)
    k = int(np.argmin(np.where(ahead > 0, ahead, np.inf)))
    return (-np.inf, float(spans[k, 0])) if direction > 0 else (float(spans[k, 1]), np.inf)


def _place_car_park_cars(agents: AgentList, rng, street: Street, busyness: float) -> None:
    """Cars in the car parks' bays, ``BAYS_TAKEN`` of them, a quarter reversed in. A car fits
    its bay: width up to 2.25 m (bays 2.6 m apart), length up to 5.2 m."""
    for park in street.car_parks:
        for s, d, yaw in zip(*bay_poses(park, street.section.pavement_outer)):
            size = sample_size("vehicle.car", rng)
            size[0] = min(size[0], 2.25)
            size[1] = min(size[1], 5.2)
            taken = rng.random() < BAYS_TAKEN[0] + BAYS_TAKEN[1] * busyness
            reversed_in = rng.random() < 0.25
            if taken:
                agents.add("vehicle.car", size, p0=float(s), offset=float(d),
                           yaw_offset=float(yaw + (np.pi if reversed_in else 0.0) + rng.normal(0.0, 0.03)),
                           parked=True)


def _place_cyclists(agents: AgentList, rng, street: Street, busyness: float) -> None:
    """Riders in the bike lanes (they ride round turns: the bike lane's radius stays positive),
    parked bicycles at the kerb away from junctions where the route turns."""
    section = street.section
    spans = _turn_spans(street)
    for direction in (+1, -1):
        side = -section.drive_side * direction
        offset = side * (section.bike_lane_inner + 0.75)
        speed = float(np.clip(rng.normal(4.0, 1.0), 2.0, 7.0))
        for position in _fill_line(rng, 0.0, street.route.length, RIDER_GAP / busyness,
                                   float(rng.uniform(0, RIDER_GAP / busyness))):
            # 5 % motorcycles and scooters (was 10 %, our choice): held motorcycles inside
            # trainval's 0.37 per keyframe (+-20 %) once the bike lanes carried more riders.
            category = "vehicle.bicycle" if rng.random() < 0.95 else "vehicle.motorcycle"
            size = sample_size(category, rng)
            size[2] = max(size[2], 1.55)  # the box includes the rider
            agents.add(category, size, p0=position, offset=offset, speed=speed, direction=direction, rider=True)
    # Parked bicycles at the kerb, across the pavement edge.
    for side in (+1, -1):
        for position in _fill_line(rng, 0.0, street.route.length, PARKED_BICYCLE_GAP,
                                   float(rng.uniform(0, PARKED_BICYCLE_GAP))):
            size = sample_size("vehicle.bicycle", rng)
            size[2] = min(size[2], 1.15)
            if not _in_spans(position, spans, margin=1.0):
                agents.add("vehicle.bicycle", size, p0=position, offset=side * (section.kerb + 0.35),
                           yaw_offset=float(rng.choice([0.0, np.pi]) + rng.normal(0, 0.05)), parked=True)


def _place_pedestrians(agents: AgentList, rng, street: Street, busyness: float) -> None:
    """Walking parties on each pavement and people standing by the building fronts.

    Three walking lines per pavement, 1 m apart: the two nearer the kerb carry one stream,
    whose groups walk abreast (a triad as a V, its middle walker between the lines), the
    third the other way, whose groups walk in file, too narrow to pass abreast. Each
    stream keeps one direction and pace, so its parties never meet. Parties heading for a
    junction where the route turns wait at its edge, one behind the other."""
    section = street.section
    length = street.route.length
    spans = _turn_spans(street)
    for side in (+1, -1):
        abreast_direction = int(rng.choice([1, -1]))
        streams = ((WALKING_LINES[:2], abreast_direction), (WALKING_LINES[2:], -abreast_direction))
        for insets, direction in streams:
            speed = float(np.clip(rng.normal(1.35, 0.15), 0.9, 1.8))
            waiting: dict[float, float] = {}  # junction edge -> metres of queue already standing there
            parties = list(_walking_parties(rng, length, WALKER_GAP / busyness, insets, direction))
            for front, members in (parties if direction < 0 else parties[::-1]):  # front of the queue first
                positions = front - direction * members[:, 1]
                if any(_in_spans(p, spans, margin=1.0) for p in positions):
                    continue
                lo, hi = _walk_range(front, direction, spans)
                edge = hi if direction > 0 else lo
                queued = waiting.get(edge, 0.0)
                waiting[edge] = queued + float(members[:, 1].max()) + WALKER_QUEUE_SPACING
                for (inset, back), position in zip(members, positions):
                    category = "human.pedestrian.child" if rng.random() < 0.03 else "human.pedestrian.adult"
                    agents.add(category, sample_size(category, rng), p0=float(position),
                               offset=side * (section.kerb + inset), speed=speed, direction=direction,
                               p_range=_queued_range(lo, hi, direction, queued + back))
        for position in _fill_line(rng, 0.0, length, STANDING_GAP / busyness, float(rng.uniform(0, 100))):
            category = "human.pedestrian.adult"
            offset = side * (section.kerb + PAVEMENT_WIDTH - 0.2)
            size = sample_size(category, rng)
            if not _in_spans(position, spans, margin=1.0):
                agents.add(category, size, p0=position, offset=offset, yaw_offset=float(rng.uniform(-np.pi, np.pi)))


def party_formation(size: int, insets: tuple) -> np.ndarray:
    """(size, 2) members of a walking party: their line's inset from the kerb (m) and how far
    each walks behind the party's front (m). On two lines a pair walks abreast and a triad as
    a V; on one line a party walks in file, ``WALKER_QUEUE_SPACING`` apart."""
    if len(insets) == 1:
        return np.column_stack([np.full(size, insets[0]), WALKER_QUEUE_SPACING * np.arange(size)])
    formation = np.array([[insets[0], 0.0], [insets[1], 0.0], [(insets[0] + insets[1]) / 2, V_SETBACK]])
    return formation[:size]


def _walking_parties(rng: np.random.Generator, length: float, gap_mean: float, insets: tuple, direction: int):
    """(front, members) of the parties of a stream walking ``direction`` along [0, length),
    fronts ascending: members as `party_formation`; a lone walker takes one of the stream's
    lines at random. Parties are at least 2.5 m apart from the last member of one to the
    front of the next."""
    position = float(rng.uniform(0, 100))
    while position < length:
        size = int(rng.choice(PARTY_SIZES, p=PARTY_SIZE_SHARES))
        lines = (insets[int(rng.integers(len(insets)))],) if size == 1 else insets
        members = party_formation(size, lines)
        depth = float(members[:, 1].max())
        yield (position + depth if direction > 0 else position), members
        position += depth + max(float(rng.exponential(gap_mean)), 2.5)


def _queued_range(lo: float, hi: float, direction: int, behind: float) -> tuple[float, float]:
    """Path range of a walker heading for the end of [lo, hi] that stops ``behind`` metres short
    of it: behind the walkers already waiting there and its own party's front."""
    return (lo, hi - behind) if direction > 0 else (lo + behind, hi)


def _place_car_park_walkers(agents: AgentList, rng, street: Street, busyness: float) -> None:
    """People walking along the aisles between a car park's rows of bays, one line each way a
    metre either side of the aisle's middle; a walker stops at the aisle's end, behind those
    who stopped there before."""
    outer = street.section.pavement_outer
    for park in street.car_parks:
        lo, hi = park.s0 + 0.5, park.s1 - 0.5
        for row in range(park.rows - 1):
            middle = outer + BAY_START + BAY_DEPTH + AISLE_WIDTH / 2 + row * ROW_PITCH
            for direction, inset in ((+1, -1.0), (-1, 1.0)):
                speed = float(np.clip(rng.normal(1.35, 0.15), 0.9, 1.8))
                gap = AISLE_WALKER_GAP / busyness
                positions = list(_fill_line(rng, lo, hi, gap, float(rng.uniform(0.0, gap))))
                for queued, position in enumerate(positions[::-1] if direction > 0 else positions):
                    agents.add("human.pedestrian.adult", sample_size("human.pedestrian.adult", rng), p0=position,
                               offset=park.side * (middle + inset), speed=speed, direction=direction,
                               p_range=_queued_range(lo, hi, direction, queued * WALKER_QUEUE_SPACING))


def _place_crossing_traffic(agents: AgentList, rng, street: Street, busyness: float) -> list:
    """Traffic on every arm of the crossing streets. Where the route turns, and on the arms
    of a straight-across junction that wait (1 - ``FLOWING_ARM_SHARE``), a queue at the stop
    line and cars arriving at its tail; on the other arms of a straight-across junction a
    stream that drives through the junction, ``TURN_IN_SHARE`` of it turning onto the route.
    Every arm has cars driving away from the junction (those that crossed or turned before,
    and the stream that goes through). Returns the rows of the road users that cross or join
    the route's carriageway: :func:`_drop_junction_conflicts` keeps those that meet nobody."""
    crossing: list[int] = []
    for intersection in street.intersections:
        flowing = {arm: intersection.through and bool(rng.random() < FLOWING_ARM_SHARE) for arm in intersection.arms}
        speeds = {arm: float(np.clip(rng.normal(6.0, 1.5), 3.5, 8.0)) for arm in intersection.arms if flowing[arm]}
        through: dict[int, list] = {}
        for arm in intersection.arms:
            if flowing[arm] and -arm not in intersection.arms:  # a side street: every car turns
                _place_flowing_arm(agents, rng, street, intersection, arm, busyness, speeds[arm], crossing,
                                   turn_share=1.0)
            elif flowing[arm]:
                through[-arm] = _place_flowing_arm(agents, rng, street, intersection, arm, busyness, speeds[arm],
                                                   crossing)
            else:
                _place_arriving_queue(agents, rng, street, intersection, arm, busyness)
        for arm in intersection.arms:
            _place_departing_lane(agents, rng, street, intersection, arm, busyness, speed=speeds.get(-arm),
                                  upstream=through.get(arm, []), crossing=crossing)
    return crossing


def _place_flowing_arm(agents: AgentList, rng, street: Street, intersection: Intersection, arm: int,
                       busyness: float, speed: float, crossing: list, turn_share: float = TURN_IN_SHARE) -> list:
    """Cars arriving along ``arm`` at one shared ``speed`` that reach the junction during the
    scene: those that turn onto the route are added here (paths of their own); those that go
    straight on are returned as (category, size, distance from the junction centre) for the
    departing lane of the opposite arm, which they share."""
    section = street.section
    radius = turn_radius(speed)
    arm_lane = section.drive_side * arm * LANE_WIDTH / 2  # the arriving lane (_arm_line, direction -arm)
    through = []
    distance = section.pavement_outer + float(rng.uniform(0.0, 30.0))
    while distance < min(speed * (SCENE_SECONDS - 2.0), ARM_LENGTH - 20.0):
        category = _vehicle_category(rng, moving=True)
        size = sample_size(category, rng)
        distance += size[1] / 2
        if rng.random() < turn_share:
            direction = int(rng.choice([-1, 1]))
            near_side = arm * direction * section.drive_side < 0  # a turn towards the kerb
            lane = section.lanes_per_direction - 1 if near_side else 0
            d = section.lane_center(lane, direction)
            s_end = street.route.length + 50.0 if direction > 0 else -50.0
            path, _ = turn_onto_route(street.route, intersection, arm, arm_lane, direction, d, radius, s_end)
            crossing.append(len(agents.category))
            agents.add(category, size, p0=ARM_LENGTH - distance, speed=speed, path=path,
                       rider=category == "vehicle.motorcycle")
        else:
            through.append((category, size, distance))
        distance += size[1] / 2 + 2.5 + float(rng.exponential(30.0 / busyness))
    return through


def _place_driveways(agents: AgentList, rng, street: Street, ego: EgoDrive,
                     crossing: list) -> list[tuple[int, float, float]]:
    """Cars waiting in driveways beside the ego's drive, nose to the road just behind the
    pavement, that pull out during the scene and turn into the near or far lane (stopped,
    driver on board, until they go). Returns [(side, s_min, s_max)] of the driveways, kept
    free of kerb-side parking and buildings. The cars' rows are added to ``crossing``."""
    section = street.section
    travel = ego.speed * SCENE_SECONDS + 0.5 * ego.accel * SCENE_SECONDS**2
    spans = _turn_spans(street)
    driveways: list[tuple[int, float, float]] = []
    for _ in range(int(rng.poisson(DRIVEWAYS_PER_SCENE))):
        side = int(rng.choice([-1, 1]))
        s = float(rng.uniform(ego.s0 - 30.0, ego.s0 + travel + 30.0))
        direction = int(rng.choice([-1, 1]))
        speed = float(rng.uniform(3.0, 5.0))
        wait = float(rng.uniform(0.0, 14.0))
        category = "vehicle.car"
        size = sample_size(category, rng)
        around = np.linspace(s - 30.0, s + 30.0, 13)
        clear = (np.all(street.route.curvature_at(around) == 0.0) and 30.0 < s < street.route.length - 30.0
                 and not street.near_intersection(np.array([s]), margin=15.0)[0]
                 and not _in_spans(s, spans, margin=15.0)
                 and not any(p.side == side and p.s0 - 6.0 < s < p.s1 + 6.0 for p in street.car_parks)
                 and not any(d_side == side and lo - 6.0 < s < hi + 6.0 for d_side, lo, hi in driveways))
        if not clear:
            continue
        near_side = side * direction * section.drive_side < 0  # a turn towards the kerb
        d = section.lane_center(section.lanes_per_direction - 1 if near_side else 0, direction)
        xy, heading = street.route.pose(np.array([s]))
        mouth = Intersection(s, xy[0], float(heading[0] + np.pi / 2), arms=(side,), side_street=True)
        start = section.pavement_outer + 0.3 + size[1] / 2  # the car's centre, from the centreline
        s_end = street.route.length + 50.0 if direction > 0 else -50.0
        path, _ = turn_onto_route(street.route, mouth, side, 0.0, direction, d, turn_radius(speed), s_end,
                                  arm_length=start)
        crossing.append(len(agents.category))
        agents.add(category, size, p0=-speed * wait, speed=speed, path=path, p_range=(0.0, np.inf))
        driveways.append((side, s - 3.5, s + 3.5))
    return driveways


def _turn_off_route(agents: AgentList, rng, street: Street, crossing: list) -> None:
    """Moving vehicles in the route's lanes that reach a straight-across junction during the
    scene turn into the crossing street (``TURN_OFF_SHARE`` of them), at their own speed."""
    section = street.section
    junctions = [i for i in street.intersections if i.through]
    if not junctions:
        return
    junction_s = np.array([i.s for i in junctions])
    for row, category in enumerate(agents.category):
        speed, offset = agents.speed[row], agents.offset[row]
        lane_vehicle = (category in ("vehicle.car", "vehicle.truck", "vehicle.motorcycle")
                        and agents.path_line[row] is None and agents.path[row] is None and not agents.parked[row]
                        and agents.accel[row] == 0.0 and 2.0 < speed <= TURN_ROAD_SPEED
                        and abs(offset) < section.bike_lane_inner
                        and abs(offset - section.lane_center(int(section.lane_of(np.array([offset]))[0]),
                                                             int(agents.direction[row]))) < 1e-6)
        if not lane_vehicle or rng.random() >= TURN_OFF_SHARE:
            continue
        direction = int(agents.direction[row])
        p0 = agents.p0[row]
        arrival = (junction_s - p0) * direction / speed
        ahead = np.flatnonzero((arrival > 2.0) & (arrival < SCENE_SECONDS - 3.0))
        if len(ahead) == 0:
            continue
        junction = junctions[int(ahead[np.argmin(arrival[ahead])])]
        arm = int(rng.choice(junction.arms))
        arm_lane = -section.drive_side * arm * LANE_WIDTH / 2  # the departing lane (_arm_line, direction arm)
        path, length = turn_off_route(street.route, junction, p0, direction, offset, arm, arm_lane,
                                      turn_radius(speed))
        agents.path[row] = path
        agents.p0[row], agents.direction[row], agents.offset[row] = 0.0, 1, 0.0
        agents.p_range[row] = (-np.inf, length - agents.size[row][1] / 2)
        crossing.append(row)


def _drop_junction_conflicts(agents: Agents, rows: list, street: Street, ego: EgoDrive,
                             rng: np.random.Generator) -> Agents:
    """The agents with the road users of ``rows`` (crossing or joining the route at a junction
    or from a driveway) kept clear of everyone: one whose body comes within ``CLEARANCE`` of
    another road user's or the ego's at any instant of the scene (checked every
    ``JUNCTION_CHECK_STEP`` s) gives way, i.e. comes 1.5-5 s later along its path, up to
    ``GIVE_WAY_TRIES`` times; after that it is left out, so every track stays collision-free."""
    if not rows:
        return agents
    times = np.arange(0.0, SCENE_SECONDS + 1e-9, JUNCTION_CHECK_STEP)
    checked = np.array(sorted(set(rows)))
    clash = np.zeros(len(agents), bool)
    for attempt in range(GIVE_WAY_TRIES + 1):
        found = (closest_approach(agents, street, checked, times, ego) < CLEARANCE).any(axis=1)
        clash[:] = False
        clash[checked[found]] = True
        if not found.any() or attempt == GIVE_WAY_TRIES:
            break
        late = checked[found]
        p0 = agents.p0.copy()
        p0[late] -= agents.direction[late] * agents.speed[late] * rng.uniform(1.5, 5.0, len(late))
        agents = replace(agents, p0=p0)
        # Only the moved road users can have new conflicts (with anyone, moved or not).
        checked = late
    return without(agents, clash)


def _arm_line(street: Street, intersection: Intersection, arm: int, direction: int) -> tuple[float, float, float]:
    """Straight path (origin x, y, heading) of the lane of ``arm`` used by traffic moving in
    ``direction`` along the crossing street (the lane on the drive side of its centreline)."""
    heading = intersection.heading
    lane_d = -street.section.drive_side * direction * LANE_WIDTH / 2
    origin = intersection.center + lane_d * np.array([-np.sin(heading), np.cos(heading)])
    return (float(origin[0]), float(origin[1]), heading)


def _place_arriving_queue(agents: AgentList, rng, street: Street, intersection: Intersection, arm: int,
                          busyness: float) -> None:
    """Stopped cars at the stop line of ``arm``, then cars that drive up at one shared speed
    and stop at the queue's tail. Each car starts at least as far behind the car ahead as
    its slot is behind that car's slot, so with one speed no gap ever shrinks below the
    slots' spacing."""
    line = _arm_line(street, intersection, arm, direction=-arm)
    slot = street.section.pavement_outer + 2.0  # distance from the junction centre
    speed = float(np.clip(rng.normal(6.6, 2.0), 3.0, 11.0))
    lead = 0.0  # how far the car's start is behind its slot: never decreases along the queue
    for k in range(int(rng.poisson(1.5 * busyness)) + int(rng.poisson(1.2 * busyness))):
        category = _vehicle_category(rng, moving=False)
        size = sample_size(category, rng)
        slot += size[1] / 2
        if k > 0 and rng.random() < 0.5:
            lead = max(lead, speed * float(rng.uniform(2.0, SCENE_SECONDS)))
        p_range = (slot, np.inf) if arm > 0 else (-np.inf, -slot)
        agents.add(category, size, p0=arm * (slot + lead), line=line, direction=-arm,
                   speed=speed if lead > 0 else 0.0, p_range=p_range)
        slot += size[1] / 2 + float(rng.uniform(1.5, 4.0))


def _place_departing_lane(agents: AgentList, rng, street: Street, intersection: Intersection, arm: int,
                          busyness: float, speed: float | None = None, upstream: Sequence = (),
                          crossing: list | None = None) -> None:
    """Cars driving away from the junction along ``arm`` at one shared speed, behind them
    the ``upstream`` cars (category, size, distance before the junction centre) of a flowing
    opposite arm that go straight through at the same ``speed``. They stop (clipped paths)
    from 120 m out backwards, front car first, before they could meet anything the
    crossing street does not hold. The rows of the through cars are added to ``crossing``."""
    line = _arm_line(street, intersection, arm, direction=arm)
    if speed is None:
        speed = float(np.clip(rng.normal(6.6, 2.0), 3.0, 11.0))
    position = street.section.pavement_outer + 2.0
    cars = [(category, size, -distance, True) for category, size, distance in reversed(upstream)]
    for _ in range(int(rng.poisson(2.0 * busyness))):
        category = _vehicle_category(rng, moving=True)
        size = sample_size(category, rng)
        position += float(rng.exponential(30.0 / busyness)) + size[1] / 2
        cars.append((category, size, position, False))
        position += size[1] / 2 + 2.5
    stop = DEPARTURE_STOP  # where the rear of the car ahead stops
    for category, size, position, crosses in reversed(cars):
        center = stop - size[1] / 2
        if position < center:
            p_range = (-np.inf, center) if arm > 0 else (-center, np.inf)
            if crosses and crossing is not None:
                crossing.append(len(agents.category))
            agents.add(category, size, p0=arm * position, line=line, direction=arm, speed=speed,
                       p_range=p_range, rider=category == "vehicle.motorcycle")
            stop = center - size[1] / 2 - 2.0


def _place_roadworks(agents: AgentList, rng, street: Street, ego: EgoDrive) -> list:
    """Closed stretches of the parking lane near the ego's drive: one side, or both with
    probability ``ROADWORKS_BOTH_SIDES``. Returns [(side, s_min, s_max)] so no car is parked
    there; [] where there is no room (no roadworks then)."""
    first = int(rng.choice([-1, 1]))
    sides = (first, -first) if rng.random() < ROADWORKS_BOTH_SIDES else (first,)
    works = []
    for side in sides:
        works += _place_roadworks_site(agents, rng, street, ego, side)
    return works


def _place_roadworks_site(agents: AgentList, rng, street: Street, ego: EgoDrive, side: int) -> list:
    """A closed stretch of the parking lane, ``ROADWORKS_LENGTH`` long: barriers along its edge, a cone
    taper at each end, workers inside, and beyond each taper (``CONSTRUCTION_VEHICLE_SHARE``
    of the ends) a construction vehicle parked in the lane. The stretch is moved and shortened
    (to 30 m at least) to fit between junctions, at up to ``ROADWORKS_TRIES`` places along the
    ego's drive. Returns [(side, s_min, s_max)], or [] where none fits."""
    section = street.section
    length = float(rng.uniform(*ROADWORKS_LENGTH))
    n_cones = (int(rng.integers(*TAPER_CONES)), int(rng.integers(*TAPER_CONES)))
    n_workers = int(rng.integers(0, 4))
    plant = [bool(rng.random() < CONSTRUCTION_VEHICLE_SHARE) for _ in range(2)]
    plant_size = [sample_size("vehicle.construction", rng) for _ in range(2)]
    for size in plant_size:
        size[0] = min(size[0], PARKING_WIDTH - 0.2)  # it stands in the closed parking lane
    before = 2.5 * n_cones[0] + 5.0 + (plant_size[0][1] + 2.0 if plant[0] else 0.0)
    after = 2.5 * n_cones[1] + 5.0 + (plant_size[1][1] + 2.0 if plant[1] else 0.0)
    # The ego drives past the site: its middle lies on the ego's drive (scene selection picked
    # scenes at construction sites); a site wholly ahead or behind is seen only from afar,
    # where barriers and cones are annotated mostly without a LiDAR point.
    travel = ego.speed * SCENE_SECONDS + 0.5 * ego.accel * SCENE_SECONDS**2
    starts = ego.s0 - length / 2 + rng.uniform(0.0, max(travel, 1.0), ROADWORKS_TRIES)
    for start in starts:
        lo_free, hi_free = _free_stretch(street, float(start))
        fitted = min(length, hi_free - lo_free - before - after)
        if fitted >= 30.0:
            break
    else:
        return []
    length = fitted
    start = float(np.clip(start, lo_free + before, hi_free - after - length))
    lo, hi = start - before, start + length + after
    inner = section.parking_inner
    position = start
    while position < start + length:
        size = sample_size("movable_object.barrier", rng)
        # Barriers are annotated with their long side as the width: turn them across.
        agents.add("movable_object.barrier", size, p0=position + size[0] / 2, offset=side * (inner + 0.35),
                   yaw_offset=np.pi / 2)
        position += size[0] + float(rng.uniform(0.05, 0.4))
    for end, count, step, here, size in ((start, n_cones[0], -2.5, plant[0], plant_size[0]),
                                         (position, n_cones[1], 2.5, plant[1], plant_size[1])):
        for k in range(count):
            cone = sample_size("movable_object.trafficcone", rng)
            across = inner + 0.35 + (PARKING_WIDTH - 0.7) * (k + 1) / count
            agents.add("movable_object.trafficcone", cone, p0=end + step * (k + 1), offset=side * across)
        if here:
            # 2.5 m past the taper's last cone, against the kerb, parked.
            p0 = end + np.sign(step) * (2.5 * count + 2.5 + size[1] / 2)
            agents.add("vehicle.construction", size, p0=float(p0), offset=side * (section.kerb - size[0] / 2 - 0.1),
                       direction=-side * section.drive_side, parked=True)
    for k in range(n_workers):
        category = "human.pedestrian.construction_worker"
        spread = start + length * (k + 1) / (n_workers + 1)  # apart, at least 11 m
        agents.add(category, sample_size(category, rng), p0=spread + float(rng.uniform(-1.0, 1.0)),
                   offset=side * (inner + float(rng.uniform(1.1, 1.8))), yaw_offset=float(rng.uniform(-np.pi, np.pi)))
    return [(side, lo, hi)]


def _car_park_depth(street: Street, side: int, center_s: float, frontage: float) -> float:
    """Depth of the car parks beside a building's frontage: the building stands behind them."""
    depths = [park.depth for park in street.car_parks
              if park.side == side
              and park.s0 - 2.0 < center_s + frontage / 2 and center_s - frontage / 2 < park.s1 + 2.0]
    return max(depths, default=0.0)


def _free_stretch(street: Street, s: float) -> tuple[float, float]:
    """The route interval around arc length ``s`` between the junctions (2 m clear of them)."""
    lo, hi = 0.0, street.route.length
    for junction in street.intersections:
        near, far = junction.s - junction.half_span - 2.0, junction.s + junction.half_span + 2.0
        if far <= s:
            lo = max(lo, far)
        elif near >= s:
            hi = min(hi, near)
        else:
            return s, s  # inside the junction
    return lo, hi


def _place_buildings(rng: np.random.Generator, street: Street, driveways: Sequence = ()) -> tuple[Building, ...]:
    """Blocks along both sides, set back from the pavement (and behind the car parks), none
    across a crossing street or a driveway ((side, s_min, s_max) each)."""
    buildings = []
    route = street.route
    for side in (+1, -1):
        position = 0.0
        while position < route.length:
            frontage = float(rng.uniform(8.0, 30.0))
            depth = float(rng.uniform(8.0, 16.0))
            center_s = position + frontage / 2
            on_driveway = any(d_side == side and lo - frontage / 2 < center_s < hi + frontage / 2
                              for d_side, lo, hi in driveways)
            if not on_driveway and not street.near_intersection(np.array([center_s]),
                                                                margin=frontage / 2 + PAVEMENT_WIDTH + 2.0)[0]:
                setback = float(rng.uniform(0.5, 4.0)) + _car_park_depth(street, side, center_s, frontage)
                d = side * (street.section.pavement_outer + setback + depth / 2)
                xy, heading = route.pose(np.array([center_s]), d)
                height = float(rng.choice([rng.uniform(4.0, 9.0), rng.uniform(9.0, 30.0)]))
                buildings.append(Building(xy[0], float(heading[0]), np.array([depth, frontage, height])))
            position += frontage + float(rng.exponential(3.0))
    return tuple(buildings)
