import numpy as np
import pytest

from sianms_cli.synth import radar
from sianms_cli.synth.radar import (
    RETURNS_AT_10_M,
    expected_returns,
    in_radar_field,
    radar_returns,
    returns_at_10_m,
)


def _at(distance: float, degrees: float, origin=(0.0, 0.0)) -> np.ndarray:
    """An ego-frame point ``distance`` metres from ``origin`` at ``degrees`` from the x axis."""
    angle = np.radians(degrees)
    return np.array([origin[0] + distance * np.cos(angle), origin[1] + distance * np.sin(angle)])


FRONT = tuple(radar.RADAR_MOUNTS[0, :2])


@pytest.mark.parametrize("point, inside", [
    (_at(240.0, 8.0, FRONT), True),  # far field, ±9° to 250 m
    (_at(260.0, 0.0, FRONT), False),  # beyond the far field
    (_at(100.0, 20.0, FRONT), False),  # wider than the far field, farther than the near field
    (_at(65.0, 44.0, FRONT), True),  # near field, ±45° to 70 m
    (_at(60.0, 90.0, radar.RADAR_MOUNTS[1, :2]), True),  # the front-left radar looks sideways
    (_at(60.0, 180.0), True),  # behind: the rear corner radars overlap there
])
def test_the_five_radars_fields(point, inside):
    assert in_radar_field(point) == inside


def test_the_near_fields_close_around_the_car_but_for_slivers_between_radars():
    angles = np.arange(0.0, 360.0, 0.5)
    seen = in_radar_field(np.stack([_at(40.0, a) for a in angles]))
    assert 0.98 < seen.mean() < 1.0
    assert seen[np.isin(angles, [0.0, 90.0, 180.0, 270.0])].all()


def test_returns_fall_with_range_as_nuscenes_maxima_do():
    # nuScenes' most-returning objects: 40 returns at 10 m, 10 at 50 m.
    strength = np.array([1.0, 1.0])
    mean = expected_returns(strength, np.array([_at(10.0, 0.0), _at(50.0, 0.0)]), np.array([1.0, 1.0]))
    assert mean[0] / mean[1] == pytest.approx(4.0)


def test_closer_than_five_metres_returns_no_more_than_at_five():
    points = np.array([_at(4.0, 0.0), _at(radar.NEAREST_RANGE, 0.0)])  # the front radar is at x = 3.4 m
    mean = expected_returns(np.ones(2), points, np.ones(2))
    assert mean[0] == pytest.approx(mean[1])


def test_an_occluded_object_keeps_the_floor_share_and_an_unseen_one_counts_as_occluded():
    points = np.array([_at(20.0, 0.0)] * 3)
    mean = expected_returns(np.ones(3), points, np.array([1.0, 0.0, np.nan]))
    assert mean[1] / mean[0] == pytest.approx(radar.OCCLUDED_EXPOSURE)
    assert mean[2] == mean[1]


def test_outside_every_field_there_are_no_returns():
    far_off_axis = _at(200.0, 30.0)
    assert expected_returns(np.ones(1), far_off_axis[None], np.ones(1))[0] == 0.0


def test_strength_follows_each_objects_kind():
    kinds = np.array(["traffic_cone", "car", "bus", "car"])
    np.testing.assert_array_equal(returns_at_10_m(kinds), [RETURNS_AT_10_M[k] for k in kinds])


def test_draws_are_negative_binomial_about_the_mean_and_seeded():
    """Gamma-mixed Poisson of shape k: mean m, variance m + m^2 / k, P(0) = (1 + m / k)^-k."""
    strength = np.full(40_000, 2.0)
    points = np.tile(_at(10.0, 0.0), (40_000, 1))
    first = radar_returns(np.random.default_rng(5), strength, points, np.ones(40_000))
    again = radar_returns(np.random.default_rng(5), strength, points, np.ones(40_000))
    np.testing.assert_array_equal(first, again)
    mean, k = 2.0 * radar.RETURNS_SCALE, radar.RETURNS_DISPERSION
    assert first.dtype == np.int64
    assert first.mean() == pytest.approx(mean, rel=0.03)
    assert first.var() == pytest.approx(mean + mean**2 / k, rel=0.08)
    assert (first == 0).mean() == pytest.approx((1 + mean / k) ** -k, abs=0.01)
