import numpy as np
import pytest

from sianms_cli.synth.manoeuvres import CLEARANCE, closest_approach
from sianms_cli.synth.road import BAY_DEPTH, BAY_START, ROW_PITCH
from sianms_cli.synth.world import (
    ABREAST_SPACING,
    FOLLOWING_HEADWAY,
    KERB_GAP,
    KEYFRAME_HZ,
    QUEUE_VEHICLES,
    SCENE_SECONDS,
    SIZE_STATS,
    STANDSTILL_GAP,
    V_SETBACK,
    party_formation,
    plan_scene,
)

SEEDED = range(40)
"""The seeded set of scenes in which every kind of place must appear."""
VARIED = (0, 1, 2, 3, 4, 9, 10, 14, 36)
"""Seeds whose plans cover straight drives, turns at T and 4-way junctions, roadworks,
perpendicular and diagonal car parks, arterials with a median and cross traffic that turns
and goes through junctions (checked by test_the_varied_plans_cover_every_place)."""


def _plan(seed: int):
    return plan_scene(np.random.default_rng(seed), drive_side=+1 if seed % 2 else -1)


@pytest.fixture(scope="module")
def plans():
    return [_plan(seed) for seed in VARIED]


@pytest.fixture(scope="module")
def seeded():
    return [_plan(seed) for seed in SEEDED]


def _turning(plan) -> bool:
    return any(not junction.through for junction in plan.street.intersections)


def _times():
    return np.arange(0.0, SCENE_SECONDS, 1.0 / KEYFRAME_HZ)


def test_plan_is_deterministic():
    for seed in (5, 36):
        a = plan_scene(np.random.default_rng(seed), drive_side=1)
        b = plan_scene(np.random.default_rng(seed), drive_side=1)
        for field in ("p0", "size", "offset", "line", "speed", "p_range", "yaw_offset"):
            np.testing.assert_array_equal(getattr(a.agents, field), getattr(b.agents, field))
        np.testing.assert_array_equal(a.route.lengths, b.route.lengths)
        np.testing.assert_array_equal(a.route.curvatures, b.route.curvatures)
        assert [(i.s, i.heading, i.arms) for i in a.street.intersections] == \
            [(i.s, i.heading, i.arms) for i in b.street.intersections]
        assert a.street.car_parks == b.street.car_parks
        assert len(a.buildings) == len(b.buildings)


def test_every_place_type_appears_in_the_seeded_scenes(seeded):
    turns = [tuple(i.arms for i in p.street.intersections if not i.through) for p in seeded]
    assert sum(map(bool, turns)) == 18  # 45 %: nuScenes key frames are 73.9 % go-straight (TURN_SHARE)
    assert ((-1,),) in turns and ((-1,), (1,)) in turns  # T and 4-way junctions
    assert any(i.through for p in seeded for i in p.street.intersections)
    angles = {round(float(np.degrees(c.angle))) for p in seeded for c in p.street.car_parks}
    assert angles == {90, 60, 45}
    assert {c.rows for p in seeded for c in p.street.car_parks} == {1, 2, 3}
    assert sum(p.roadworks for p in seeded) == 15  # of 0.75 x 0.65 = 49 %, less those without room between junctions
    assert sum(_roadworks_sides(p) == 2 for p in seeded) >= 2  # both parking lanes closed
    assert sum(_parked(p, "vehicle.construction").any() for p in seeded) >= 10  # at sites and at the kerb
    assert sum(_parked(p, "vehicle.trailer").any() for p in seeded) >= 15
    assert sum(p.street.section.median > 0 for p in seeded) == 4  # arterials, 3 lanes each way
    assert sum(_turning_in(p).any() for p in seeded) >= 4 and sum(_turning_off(p).any() for p in seeded) >= 4
    assert sum(_through_crossing(p).any() for p in seeded) >= 4
    assert sum(_driveway(p).any() for p in seeded) >= 4
    assert sum(any(i.side_street for i in p.street.intersections) for p in seeded) >= 4


def _roadworks_sides(plan) -> int:
    """How many sides of the street have barriers (a closed parking lane)."""
    barriers = plan.agents.category == "movable_object.barrier"
    return len(set(np.sign(plan.agents.offset[barriers]).tolist()))


def _parked(plan, category: str) -> np.ndarray:
    """(N,) bool: parked road users of ``category``."""
    return plan.agents.parked & (plan.agents.category == category)


def _turning_in(plan) -> np.ndarray:
    """(N,) bool: road users that turn from a crossing street onto the route."""
    start, _, _ = plan.agents.pose(plan.route, 0.0)
    _, d = plan.route.to_route_frame(start[:, :2])
    has_path = np.array([path is not None for path in plan.agents.path], dtype=bool)
    return has_path & (np.abs(d) > plan.street.section.pavement_outer)


def _driveway(plan) -> np.ndarray:
    """(N,) bool: cars waiting in a driveway, just behind the pavement, to pull out."""
    start, _, speed = plan.agents.pose(plan.route, 0.0)
    _, d = plan.route.to_route_frame(start[:, :2])
    outer = plan.street.section.pavement_outer
    return _turning_in(plan) & (np.abs(d) < outer + 4.0) & (speed == 0.0)


def _turning_off(plan) -> np.ndarray:
    """(N,) bool: road users that turn off the route into a crossing street."""
    has_path = np.array([path is not None for path in plan.agents.path], dtype=bool)
    return has_path & ~_turning_in(plan)


def _through_crossing(plan) -> np.ndarray:
    """(N,) bool: crossing-street road users that drive across the route during the scene."""
    side = np.stack([np.sign(plan.route.to_route_frame(plan.agents.pose(plan.route, t)[0][:, :2])[1])
                     for t in (0.0, SCENE_SECONDS)])
    return plan.agents.on_line & (side[0] != side[1])


def test_the_varied_plans_cover_every_place(plans):
    turns = {tuple(i.arms for i in p.street.intersections if not i.through) for p in plans}
    assert turns >= {(), ((-1,),), ((-1,), (1,))}
    assert any(p.street.section.median > 0 for p in plans)
    assert any(_turning_in(p).any() for p in plans) and any(_turning_off(p).any() for p in plans)
    assert any(_through_crossing(p).any() for p in plans)
    assert any(_driveway(p).any() for p in plans)
    assert any(i.side_street for p in plans for i in p.street.intersections)
    assert {round(float(np.degrees(c.angle))) for p in plans for c in p.street.car_parks} == {90, 60, 45}
    assert any(p.roadworks for p in plans) and not all(p.roadworks for p in plans)


def test_no_two_road_users_overlap_at_any_keyframe(plans):
    for plan in plans:
        for t in _times():
            center, yaw, _ = plan.agents.pose(plan.route, t)
            radius = 0.5 * np.min(plan.agents.size[:, :2], axis=1)  # inscribed circle of each footprint
            gap = np.hypot(*(center[:, None, :2] - center[None, :, :2]).transpose(2, 0, 1))
            np.fill_diagonal(gap, np.inf)
            assert np.all(gap > radius[:, None] + radius[None, :] - 1e-9), f"overlap at t={t}"


def test_junction_traffic_keeps_clear_of_everyone_all_scene(seeded):
    """Road users that turn or drive across the route at a junction never come near another
    road user or the ego, checked finer than the planner does."""
    times = np.arange(0.0, SCENE_SECONDS + 1e-9, 0.025)
    checked = 0
    for plan in seeded:
        rows = np.flatnonzero(_turning_in(plan) | _turning_off(plan) | _through_crossing(plan))
        if len(rows):
            clearance = closest_approach(plan.agents, plan.street, rows, times, plan.ego)
            assert clearance.min() > CLEARANCE - 0.3  # what 0.025 s can add between two 0.05 s checks
            checked += len(rows)
    assert checked >= 20


def test_turning_tracks_have_consistent_velocities(seeded, track_yaws):
    """Finite differences of a turning road user's positions give its stated speed, its yaw
    points where it goes, and it ends up square to where it started."""
    turning = 0
    for plan in seeded:
        rows = np.flatnonzero(_turning_in(plan) | _turning_off(plan))
        headings = track_yaws(plan, rows)
        if len(rows):
            swing = np.abs(np.angle(np.exp(1j * (headings[-1] - headings[0]))))
            turning += int(np.sum(np.abs(swing - np.pi / 2) < 0.05))
    assert turning >= 5


def test_a_median_splits_the_carriageways():
    plan = _plan(0)
    section = plan.street.section
    assert section.lanes_per_direction == 3 and 2.0 <= section.median <= 6.0
    on_route = np.array([path is None for path in plan.agents.path], dtype=bool) & ~plan.agents.on_line
    lanes = plan.agents.offset[(plan.agents.speed > 0) & on_route
                               & np.isin(plan.agents.category, ["vehicle.car", "vehicle.truck"])]
    assert np.all(np.abs(lanes) > section.median / 2 + 1.0)  # nobody drives on the median
    xy, _ = plan.route.pose(np.array([plan.ego.s0, plan.ego.s0]), np.array([0.0, section.lane_center(0, 1)]))
    klass, _, _ = plan.street.surface(xy)
    assert klass.tolist() == [2, 0]  # planted median, asphalt


def test_nobody_sits_on_the_ego(plans):
    for plan in plans:
        for t in _times():
            center, _, _ = plan.agents.pose(plan.route, t)
            ego_xy, _ = plan.ego.pose(plan.route, t)
            assert np.min(np.hypot(*(center[:, :2] - ego_xy).T)) > 2.0


def test_speeds_are_consistent_with_positions(plans):
    dt = 1e-3
    for plan in plans:
        for t in (3.0, 11.0, 16.0):
            center, _, speed = plan.agents.pose(plan.route, t)
            later, _, _ = plan.agents.pose(plan.route, t + dt)
            moved = np.hypot(*(later[:, :2] - center[:, :2]).T) / dt
            np.testing.assert_allclose(moved, speed, atol=2e-3)


def test_turning_tracks_head_where_they_move(plans):
    """On the turn and on the crossing streets, a moving road user's yaw is its direction of
    travel (or the opposite, for the route's oncoming traffic whose path runs backwards)."""
    dt = 1e-3
    turning = [p for p in plans if _turning(p)]
    assert turning
    for plan in turning:
        vehicles = np.array([c.startswith("vehicle.") for c in plan.agents.category])
        for t in np.arange(0.0, SCENE_SECONDS, 2.5):
            center, yaw, speed = plan.agents.pose(plan.route, t)
            later, _, _ = plan.agents.pose(plan.route, t + dt)
            moving = vehicles & (speed > 1.0)
            step = later[moving, :2] - center[moving, :2]
            motion = np.arctan2(step[:, 1], step[:, 0])
            error = np.angle(np.exp(1j * (motion - yaw[moving])))
            assert np.all(np.abs(error) < 0.06)


def test_the_ego_turns_through_its_junction(plans):
    for plan in (p for p in plans if _turning(p)):
        junction = next(i for i in plan.street.intersections if not i.through)
        start = plan.ego.s(0.0)
        end = plan.ego.s(SCENE_SECONDS)
        assert start < junction.s - junction.half_span and junction.s + junction.half_span < end
        _, yaw0 = plan.ego.pose(plan.route, 0.0)
        _, yaw1 = plan.ego.pose(plan.route, SCENE_SECONDS)
        np.testing.assert_allclose(abs(np.angle(np.exp(1j * (yaw1 - yaw0)))), np.pi / 2, atol=1e-9)


def test_crossing_streets_carry_moving_traffic(plans):
    moving = 0
    for plan in plans:
        on_line = plan.agents.on_line
        speeds = np.stack([plan.agents.pose(plan.route, t)[2] for t in _times()])
        moving += int(np.any(speeds[:, on_line] > 1.0, axis=0).sum())
    assert moving >= 10, "crossing streets hold queues only"


def test_car_park_cars_stand_in_their_bays_at_the_bay_angle(plans):
    for plan in plans:
        parked = plan.agents.parked & (plan.agents.category == "vehicle.car")
        in_park = parked & plan.street.in_car_park(plan.agents.p0, plan.agents.offset)
        for park in plan.street.car_parks:
            mine = in_park & (np.sign(plan.agents.offset) == park.side) \
                & (plan.agents.p0 > park.s0) & (plan.agents.p0 < park.s1)
            assert mine.any()
            into = np.abs(plan.agents.offset[mine]) - plan.street.section.pavement_outer - BAY_START - BAY_DEPTH / 2
            row = into / ROW_PITCH
            np.testing.assert_allclose(row, np.round(row), atol=1e-9)  # on a row's centre line
            assert set(np.round(row).astype(int)) <= set(range(park.rows))
            relative = np.mod(plan.agents.yaw_offset[mine] - park.side * park.angle + np.pi / 2, np.pi) - np.pi / 2
            assert np.all(np.abs(relative) < 0.15)  # nose in or reversed in, 0.03 rad spread


def test_kerb_parked_vehicles_stand_in_line_with_room_to_pull_out(seeded):
    """Along one parking lane, parked vehicles queue end to end at least KERB_GAP[0] apart, and
    densely: the median gap is under 10 m (8.7 m; the sparse kerb before left 31.5 m)."""
    gaps = []
    for plan in seeded:
        agents, section = plan.agents, plan.street.section
        if not section.parking:
            continue
        in_lane = (np.abs(agents.offset) > section.parking_inner) & (np.abs(agents.offset) < section.kerb)
        for side in (+1, -1):
            mine = agents.parked & ~agents.on_line & in_lane & (np.sign(agents.offset) == side) \
                & (agents.category != "vehicle.bicycle")
            order = np.argsort(agents.p0[mine])
            p0, length = agents.p0[mine][order], agents.size[mine][order, 1]
            gaps.extend(np.diff(p0) - (length[1:] + length[:-1]) / 2)
    gaps = np.array(gaps)
    assert len(gaps) > 200 and gaps.min() >= KERB_GAP[0] - 1e-9
    assert np.median(gaps) < 10.0


def test_back_rows_of_car_parks_hold_cars(seeded):
    back_row = 0
    for plan in seeded:
        cars = plan.agents.parked & (plan.agents.category == "vehicle.car")
        into = np.abs(plan.agents.offset[cars]) - plan.street.section.pavement_outer
        back_row += int((into > BAY_START + ROW_PITCH).sum())
    assert back_row >= 50


def test_people_walk_the_aisles_of_car_parks_and_stop_at_their_ends(seeded):
    walkers = 0
    for plan in seeded:
        agents, street = plan.agents, plan.street
        human = np.char.startswith(agents.category.astype(str), "human.")
        for park in street.car_parks:
            across = park.side * agents.offset - street.section.pavement_outer
            mine = human & street.in_car_park(agents.p0, agents.offset) & (np.sign(agents.offset) == park.side) \
                & (agents.p0 > park.s0) & (agents.p0 < park.s1)
            assert not park.in_bay_row(across[mine]).any()
            assert np.all(agents.p_range[mine, 0] >= park.s0) and np.all(agents.p_range[mine, 1] <= park.s1)
            walkers += int(mine.sum())
    assert walkers >= 30


def test_sizes_stay_within_two_standard_deviations(plans):
    agents = plans[0].agents
    for category in set(agents.category):
        mean, std = (np.array(v) for v in SIZE_STATS[category])
        sizes = agents.size[agents.category == category]
        if category == "vehicle.bicycle":
            sizes = sizes[:, :2]  # heights follow the rider
            mean, std = mean[:2], std[:2]
        assert np.all(sizes >= mean - 2 * std - 1e-9) and np.all(sizes <= mean + 2 * std + 1e-9)


def test_attributes_follow_motion(plans):
    plan = plans[1]
    _, _, speed = plan.agents.pose(plan.route, 5.0)
    names = plan.agents.attributes(speed)
    cars = plan.agents.category == "vehicle.car"
    assert set(names[cars]) <= {"vehicle.moving", "vehicle.parked", "vehicle.stopped"}
    assert np.all((names[cars] == "vehicle.moving") == (speed[cars] > 0.2))
    assert np.all(names[cars & plan.agents.parked] == "vehicle.parked")
    barriers = plan.agents.category == "movable_object.barrier"
    assert np.all(names[barriers] == "")


def test_class_mix_is_car_dominated(plans):
    categories = np.concatenate([p.agents.category for p in plans])
    cars = np.mean(categories == "vehicle.car")
    pedestrians = np.mean([c.startswith("human.pedestrian") for c in categories])
    assert 0.3 < cars < 0.75  # of every road user along the whole route, annotated or not
    assert 0.1 < pedestrians < 0.45
    assert max(set(categories), key=list(categories).count) == "vehicle.car"


def test_roadworks_sites_close_the_parking_lane_with_plant_beyond_the_tapers(seeded):
    """Barriers line the closed parking lane, cones taper off each end, and construction
    vehicles stand parked against the kerb beyond a taper, clear of every cone."""
    sites = 0
    for plan in (p for p in seeded if p.roadworks):
        agents, section = plan.agents, plan.street.section
        for side in (-1, 1):
            mine = np.sign(agents.offset) == side
            barriers = mine & (agents.category == "movable_object.barrier")
            if not barriers.any():
                continue
            sites += 1
            assert np.allclose(np.abs(agents.offset[barriers]), section.parking_inner + 0.35)
            cones = mine & (agents.category == "movable_object.trafficcone") & ~agents.on_line
            assert cones.sum() >= 2 * 6
            plant = mine & (agents.category == "vehicle.construction")
            assert np.all(agents.parked[plant]) and np.all(agents.speed[plant] == 0.0)
            assert np.all(np.abs(agents.offset[plant]) + agents.size[plant, 0] / 2 <= section.kerb)
            for row in np.flatnonzero(plant):
                gap = np.abs(agents.p0[cones] - agents.p0[row]) - agents.size[row, 1] / 2
                assert gap.min() >= 2.0  # past the taper's last cone
    assert sites >= 10


def test_trailers_and_construction_vehicles_only_stand_parked(seeded):
    found = set()
    for plan in seeded:
        _, _, speed = plan.agents.pose(plan.route, 10.0)
        names = plan.agents.attributes(speed)
        for category in ("vehicle.trailer", "vehicle.construction"):
            rows = plan.agents.category == category
            found |= {category} if rows.any() else set()
            assert np.all(plan.agents.parked[rows]) and np.all(plan.agents.speed[rows] == 0.0)
            assert np.all(names[rows] == "vehicle.parked")
    assert found == {"vehicle.trailer", "vehicle.construction"}


def test_parked_and_ridden_bicycles_appear(seeded):
    bicycles = [p.agents.category == "vehicle.bicycle" for p in seeded]
    parked = sum(int(np.sum(b & p.agents.parked)) for b, p in zip(bicycles, seeded))
    ridden = sum(int(np.sum(b & p.agents.rider)) for b, p in zip(bicycles, seeded))
    assert parked >= 25 and ridden >= 10


def _pavement_walkers(plan) -> np.ndarray:
    """(N,) bool: people walking along a pavement (not in car parks, not crossing)."""
    on_route = ~plan.agents.on_line & np.array([path is None for path in plan.agents.path], dtype=bool)
    inset = np.abs(plan.agents.offset) - plan.street.section.kerb
    walking = plan.agents.speed > 0
    return on_route & walking & np.isin(plan.agents.category, list(PEDESTRIANS)) & (inset > 0) & (inset < 4.0)


PEDESTRIANS = ("human.pedestrian.adult", "human.pedestrian.child")


def test_party_formations_abreast_as_a_v_and_in_file():
    np.testing.assert_array_equal(party_formation(2, (1.35, 2.35)), [[1.35, 0.0], [2.35, 0.0]])
    np.testing.assert_array_equal(party_formation(3, (1.35, 2.35)), [[1.35, 0.0], [2.35, 0.0], [1.85, V_SETBACK]])
    np.testing.assert_array_equal(party_formation(3, (3.35,)), [[3.35, 0.0], [3.35, 1.2], [3.35, 2.4]])


def test_most_pavement_walkers_walk_with_others(seeded):
    """60 % of the pavement walkers walk in a party (PARTY_SIZE_SHARES): beside a companion 1 m
    away on the other line of their stream, or within 2.4 m of one in file. Parties are 2.5 m
    apart or more, so walkers of one stream closer than that walk together."""
    together, walkers, abreast = 0, 0, 0
    for plan in seeded:
        rows = np.flatnonzero(_pavement_walkers(plan))
        a = plan.agents
        same_stream = ((np.sign(a.offset[rows, None]) == np.sign(a.offset[None, rows]))
                       & (a.direction[rows, None] == a.direction[None, rows])
                       & (a.speed[rows, None] == a.speed[None, rows]))
        along = np.abs(a.p0[rows, None] - a.p0[None, rows])
        across = np.abs(a.offset[rows, None] - a.offset[None, rows])
        close = same_stream & (along < 2.45)
        np.fill_diagonal(close, False)
        together += int(close.any(axis=1).sum())
        walkers += len(rows)
        abreast += int((close & (along < 1e-9) & (np.abs(across - ABREAST_SPACING) < 1e-9)).sum()) // 2
    assert walkers > 500 and 0.5 < together / walkers < 0.7
    assert abreast > 50


def _lane_gaps(plan, moving: bool):
    """Bumper-to-bumper gaps (m) between consecutive vehicles of each driving lane of the route
    whose traffic moves (or stands), with the lane's speed."""
    a = plan.agents
    in_lane = (~a.on_line & np.array([path is None for path in a.path], dtype=bool) & ~a.parked
               & ((a.speed > 0) == moving) & np.char.startswith(a.category.astype(str), "vehicle.")
               & (np.abs(a.offset) < plan.street.section.kerb) & (a.shift[:, 0] == 0.0))
    for lane in np.unique(a.offset[in_lane]):
        rows = np.flatnonzero(in_lane & (a.offset == lane))
        rows = rows[np.argsort(a.p0[rows])]
        yield np.diff(a.p0[rows]) - (a.size[rows[1:], 1] + a.size[rows[:-1], 1]) / 2, a.speed[rows[0]]


@pytest.mark.parametrize("moving", [False, True])
def test_lanes_carry_platoons_nose_to_tail(seeded, moving):
    """Vehicles of a lane follow each other in platoons of QUEUE_VEHICLES on average, 2 m +
    exp(1 m) + 1.5 s x speed apart (a standing queue closes up nose to tail)."""
    excess = []
    for plan in seeded:
        for gaps, speed in _lane_gaps(plan, moving):
            excess.extend(gaps - STANDSTILL_GAP[0] - FOLLOWING_HEADWAY * speed)
    excess = np.array(excess)
    assert len(excess) > 50 and excess.min() >= -1e-6
    following = excess < 5 * STANDSTILL_GAP[1]
    assert 0.7 < following.mean() < 1.0 - 0.5 / QUEUE_VEHICLES
