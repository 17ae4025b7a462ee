"""Multi-view frustum aggregation: the circle points, the axis of eqs. (1)-(2), the overlap test, the union."""

import math

import numpy as np
import pytest

from sianms_cli.geometry.frustum import points_in_frustum, rotate_to_frustum
from sianms_cli.evaluation.multiview import (
    circle_exit,
    frustum_wedge,
    frustums_overlap,
    multi_frustum_angle,
    union_frustum,
    union_members,
)

K = np.array([[100.0, 0.0, 100.0], [0.0, 100.0, 50.0], [0.0, 0.0, 1.0]])  # 200 x 100 image, 90° HFOV


def yaw_transform(angle: float, x: float = 0.0, z: float = 0.0) -> np.ndarray:
    """(4, 4) camera -> reference: turned by ``angle`` to the right about y, centred at (x, 0, z)."""
    transform = np.eye(4)
    transform[:3, :3] = rotate_to_frustum(np.eye(3), -angle).T
    transform[:3, 3] = (x, 0.0, z)
    return transform


def test_circle_exit_known_points():
    exits = circle_exit(np.array([[0.0, 0.0], [1.0, 0.0]]), np.array([[2.0, 0.0], [0.0, 3.0]]), math.sqrt(2.0))
    np.testing.assert_allclose(exits, [[math.sqrt(2.0), 0.0], [1.0, 1.0]], atol=1e-12)


def test_multi_frustum_axis_bisects_two_rays_from_one_centre():
    # Rays at 90° and 45° from +x (x right, z forward) meet the circle at p_l, p_r; p_m lies at 67.5°.
    angle = multi_frustum_angle(np.array([[0.0, 1.0]]), np.zeros((1, 2)), np.array([[1.0, 1.0]]), 10.0)
    assert angle[0] == pytest.approx(math.pi / 8, abs=1e-12)


def test_multi_frustum_axis_with_a_baseline_between_the_cameras():
    angle = multi_frustum_angle(np.array([[0.0, 1.0]]), np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]]), 10.0)
    p_l, p_r = np.array([0.0, 10.0]), np.array([1.0, math.sqrt(99.0)])
    p_m = 0.5 * (p_l + p_r)
    assert angle[0] == pytest.approx(math.pi / 2 - math.atan2(p_m[1], p_m[0]), abs=1e-12)
    axis_point = rotate_to_frustum(np.array([[p_m[0], 0.0, p_m[1]]]), angle[0])
    assert axis_point[0, 0] == pytest.approx(0.0, abs=1e-12) and axis_point[0, 2] > 0


def test_frustum_wedge_is_the_box_edges_to_the_maximum_distance():
    wedge = frustum_wedge(np.array([100.0, 40.0, 200.0, 60.0]), K, np.eye(4), 10.0)[:, [0, 2]]
    np.testing.assert_allclose(wedge, [[0.0, 0.0], [0.0, 10.0], [10.0, 10.0]], atol=1e-12)
    moved = frustum_wedge(np.array([100.0, 40.0, 200.0, 60.0]), K, yaw_transform(0.0, x=2.0), 10.0)[:, [0, 2]]
    np.testing.assert_allclose(moved, wedge + [2.0, 0.0], atol=1e-12)


def test_frustums_overlap_separating_axis():
    base = np.array([[0.0, 0.0], [0.0, 10.0], [10.0, 10.0]])
    crossing = np.array([[5.0, 0.0], [-5.0, 20.0], [0.0, 20.0]])
    touching = np.array([[10.0, 10.0], [20.0, 10.0], [20.0, 20.0]])
    apart = base + [30.0, 0.0]
    beside = np.array([[1.0, 0.0], [11.0, 10.0], [11.0, 0.0]])  # parallel edge 1/sqrt(2) m away
    result = frustums_overlap(np.stack([base] * 4), np.stack([crossing, touching, apart, beside]))
    assert result.tolist() == [True, True, False, False]


def test_union_holds_exactly_both_frustums_points():
    rng = np.random.default_rng(0)
    points = rng.uniform([-30, -2, -30], [30, 2, 30], size=(20_000, 3))
    to_a, to_b = np.eye(4), np.linalg.inv(yaw_transform(math.radians(60.0), x=0.5))
    box_a, box_b = np.array([150.0, 20.0, 199.0, 80.0]), np.array([0.0, 20.0, 60.0, 80.0])
    inside = union_members(points, (to_a, to_b), np.stack([box_a, box_b]), (K, K), 1.0, 25.0)
    in_a = points_in_frustum(points, box_a, K, 1.0, 25.0)
    in_b = points_in_frustum(points @ to_b[:3, :3].T + to_b[:3, 3], box_b, K, 1.0, 25.0)
    np.testing.assert_array_equal(inside, in_a | in_b)
    assert (in_a & ~in_b).any() and (in_b & ~in_a).any() and (in_a & in_b).any()


def test_union_frustum_puts_the_axis_on_plus_z():
    angle = multi_frustum_angle(np.array([[0.0, 1.0]]), np.zeros((1, 2)), np.array([[1.0, 1.0]]), 10.0)[0]
    on_axis = np.array([[10 * math.sin(math.pi / 8 + 0.0), 0.3, 10 * math.cos(math.pi / 8)]])
    moved = union_frustum(on_axis, np.eye(4), angle)
    np.testing.assert_allclose(moved, [[0.0, 0.3, 10.0]], atol=1e-12)
