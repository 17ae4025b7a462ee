import numpy as np
import pytest

from sianms_cli.synth.world import (
    KEYFRAME_HZ,
    SCENE_SECONDS,
    SIZE_STATS,
    plan_scene,
)


@pytest.fixture(scope="module")
def plans():
    return [plan_scene(np.random.default_rng(seed), drive_side=+1 if seed % 2 else -1) for seed in range(6)]


def _times():
    return np.arange(0.0, SCENE_SECONDS, 1.0 / KEYFRAME_HZ)


def test_plan_is_deterministic():
    a = plan_scene(np.random.default_rng(5), drive_side=1)
    b = plan_scene(np.random.default_rng(5), drive_side=1)
    np.testing.assert_array_equal(a.agents.p0, b.agents.p0)
    np.testing.assert_array_equal(a.agents.size, b.agents.size)
    assert len(a.buildings) == len(b.buildings)


def test_no_two_road_users_overlap_at_any_keyframe(plans):
    for plan in plans:
        for t in _times():
            center, yaw, _ = plan.agents.pose(plan.route, t)
            radius = 0.5 * np.min(plan.agents.size[:, :2], axis=1)  # inscribed circle of each footprint
            gap = np.hypot(*(center[:, None, :2] - center[None, :, :2]).transpose(2, 0, 1))
            np.fill_diagonal(gap, np.inf)
            assert np.all(gap > radius[:, None] + radius[None, :] - 1e-9), f"overlap at t={t}"


def test_nobody_sits_on_the_ego(plans):
    for plan in plans:
        for t in _times():
            center, _, _ = plan.agents.pose(plan.route, t)
            ego_xy, _ = plan.ego.pose(plan.route, t)
            assert np.min(np.hypot(*(center[:, :2] - ego_xy).T)) > 2.0


def test_speeds_are_consistent_with_positions(plans):
    plan = plans[0]
    dt = 1e-3
    for t in (3.0, 11.0):
        center, _, speed = plan.agents.pose(plan.route, t)
        later, _, _ = plan.agents.pose(plan.route, t + dt)
        moved = np.hypot(*(later[:, :2] - center[:, :2]).T) / dt
        np.testing.assert_allclose(moved, speed, atol=1e-3)


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
    assert 0.35 < cars < 0.75
    assert 0.1 < pedestrians < 0.45
