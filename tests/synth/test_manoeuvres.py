import numpy as np
import pytest

from sianms_cli.synth.manoeuvres import CLEARANCE, closest_approach
from sianms_cli.synth.world import SCENE_SECONDS, lateral_offset, plan_scene

VARIED = (14, 26, 37, 47)  # ego lane changes (14, 26), lane changes and pull-outs (14), pull-ins (37)


@pytest.fixture(scope="module")
def plans():
    return {seed: plan_scene(np.random.default_rng(seed), drive_side=+1 if seed % 2 else -1) for seed in VARIED}


def _kinds(plan) -> list[str]:
    """'lane', 'out' or 'in' for every agent with a manoeuvre."""
    agents, parking_inner = plan.agents, plan.street.section.parking_inner
    kinds = []
    for i in np.flatnonzero(agents.shift[:, 0] != 0.0):
        if not np.isfinite(agents.p_range[i]).any():
            kinds.append("lane")
        else:
            kinds.append("out" if abs(agents.offset[i]) > parking_inner else "in")
    return kinds


def test_every_manoeuvre_appears(plans):
    kinds = {kind for plan in plans.values() for kind in _kinds(plan)}
    assert kinds == {"lane", "out", "in"}
    # The ego moves one lane, on seed 26's 3-lane arterial and on seed 14's 2-lane street.
    assert abs(plans[26].ego.shift[0]) == pytest.approx(3.5) and abs(plans[14].ego.shift[0]) == pytest.approx(3.5)
    assert plans[26].street.section.lanes_per_direction == 3


def test_lateral_offset_is_a_smoothstep_with_zero_sideways_speed_at_its_ends():
    offset = np.array([1.75, 1.75])
    shift = np.array([[3.5, 2.0, 4.0], [0.0, 0.0, 1.0]])
    for t, expected in ((0.0, 1.75), (2.0, 1.75), (4.0, 3.5), (6.0, 5.25), (9.0, 5.25)):
        d, rate = lateral_offset(offset, shift, t)
        assert d[0] == pytest.approx(expected) and d[1] == 1.75
    assert lateral_offset(offset, shift, 2.0)[1][0] == 0.0 and lateral_offset(offset, shift, 6.0)[1][0] == 0.0
    assert lateral_offset(offset, shift, 4.0)[1][0] == pytest.approx(3.5 * 1.5 / 4.0)  # peak rate 1.5 d / T


def test_manoeuvring_tracks_have_consistent_speed_and_heading(plans, track_yaws):
    """Finite differences of positions give the stated speed, and a moving vehicle points
    where it goes (against its path for oncoming traffic, whose path runs backwards)."""
    for plan in plans.values():
        track_yaws(plan, np.flatnonzero(plan.agents.shift[:, 0] != 0.0))


def test_the_ego_heads_where_it_goes_and_ends_in_the_other_lane(plans):
    dt = 1e-3
    for seed in (26, 14):
        plan = plans[seed]
        times = np.arange(0.0, SCENE_SECONDS, 0.25)
        xy, yaw = plan.ego.track(plan.route, times)
        later, _ = plan.ego.track(plan.route, times + dt)
        motion = np.arctan2(*(later - xy).T[::-1])
        assert np.all(np.abs(np.angle(np.exp(1j * (motion - yaw)))) < 0.01)
        _, d_end = plan.route.to_route_frame(xy[-1:])
        assert d_end[0] == pytest.approx(plan.ego.offset + plan.ego.shift[0], abs=1e-6)


def test_manoeuvres_keep_their_clearance_all_scene(plans):
    times = np.arange(0.0, SCENE_SECONDS + 1e-9, 0.05)  # finer than the planner's 0.2 s check
    for plan in plans.values():
        rows = np.flatnonzero(plan.agents.shift[:, 0] != 0.0)
        clearance = closest_approach(plan.agents, plan.street, np.append(rows, len(plan.agents)), times, plan.ego)
        assert clearance.min() > CLEARANCE - 0.3  # what 0.05 s can add between two 0.2 s checks


def test_pulling_out_cars_are_stopped_until_they_go(plans):
    plan = plans[14]
    agents = plan.agents
    out = np.flatnonzero((agents.shift[:, 0] != 0.0) & np.isfinite(agents.p_range).any(axis=1)
                         & (np.abs(agents.offset) > plan.street.section.parking_inner))
    start = agents.shift[out, 1]
    before = agents.attributes(agents.pose(plan.route, float(start[0]) - 0.5)[2])[out[0]]
    after = agents.attributes(agents.pose(plan.route, float(start[0]) + 0.5)[2])[out[0]]
    assert (before, after) == ("vehicle.stopped", "vehicle.moving")


def test_clearances_equal_the_array_expression_plans_were_made_with(plans):
    """The clearance loop is a numba kernel; scenes planned when it was this numpy expression
    must be planned again to the bit."""
    from sianms_cli.synth.manoeuvres import _circles, _lower_to_clearances
    rng = np.random.default_rng(6)
    center, yaw = rng.uniform(-30.0, 30.0, (40, 2)), rng.uniform(-np.pi, np.pi, 40)
    size = np.column_stack([rng.uniform(0.5, 3.0, 40), rng.uniform(0.5, 12.0, 40)])
    circles, radius = _circles(center, yaw, size)
    rows = np.array([3, 0, 39, 17])
    worst = rng.uniform(-1.0, 5.0, (len(rows), 40))
    before = worst.copy()
    gap = np.linalg.norm(circles[rows][:, :, None, None, :] - circles[None, None, :, :, :], axis=-1)
    expected = np.minimum(worst, gap.min(axis=(1, 3)) - radius[rows][:, None] - radius[None, :])
    _lower_to_clearances(worst, circles, radius, rows)
    np.testing.assert_array_equal(worst, expected)
    assert (worst < before).any() and (worst == before).any()  # some lowered, some left
