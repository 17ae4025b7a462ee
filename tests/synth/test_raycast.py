import numpy as np
import pytest

from sianms_cli.synth.raycast import intersect_boxes, intersect_ground, intersect_parts
from sianms_cli.synth.shapes import Parts


def _parts(centers, halves, yaws):
    m = len(centers)
    return Parts(centers, halves, yaws, np.arange(m), np.zeros(m))


def test_ray_hits_front_face_at_known_t_and_normal():
    parts = _parts([[5.0, 0.0, 1.0]], [[1.0, 1.0, 1.0]], [0.0])
    t, part, normal, local = intersect_parts([0.0, 0.0, 1.0], [[1.0, 0.0, 0.0]], parts)
    assert t[0] == 4.0
    assert part[0] == 0
    np.testing.assert_array_equal(normal[0], [-1.0, 0.0, 0.0])
    np.testing.assert_array_equal(local[0], [-1.0, 0.0, 0.0])


def test_rotated_box_normal_and_local_hit():
    # Yaw pi/2 turns the part's y half extent (1 m) along global x.
    parts = _parts([[5.0, 0.0, 1.0]], [[2.0, 1.0, 1.0]], [np.pi / 2])
    t, _, normal, local = intersect_parts([0.0, 0.3, 1.2], [[1.0, 0.0, 0.0]], parts)
    assert t[0] == pytest.approx(4.0)
    np.testing.assert_allclose(normal[0], [-1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(local[0], [0.3, 1.0, 0.2], atol=1e-12)


def test_ray_missing_gives_inf_and_minus_one():
    parts = _parts([[5.0, 0.0, 1.0]], [[1.0, 1.0, 1.0]], [0.0])
    t, part, normal, _ = intersect_parts([0.0, 0.0, 1.0], [[0.0, 1.0, 0.0], [1.0, 0.0, 0.5]], parts)
    assert np.all(np.isinf(t))
    np.testing.assert_array_equal(part, [-1, -1])
    np.testing.assert_array_equal(normal, 0.0)


def test_nearest_of_two_whatever_the_order():
    for centers, nearest in (([[12.0, 0, 1], [6.0, 0, 1]], 1), ([[6.0, 0, 1], [12.0, 0, 1]], 0)):
        parts = _parts(centers, [[1.0, 1, 1]] * 2, [0.0, 0.0])
        t, part, _, _ = intersect_parts([0.0, 0.0, 1.0], [[1.0, 0.0, 0.0]], parts)
        assert part[0] == nearest
        assert t[0] == 5.0


def test_t_is_in_units_of_the_direction_length_and_t_max_cuts():
    parts = _parts([[5.0, 0.0, 1.0]], [[1.0, 1.0, 1.0]], [0.0])
    t, _, _, _ = intersect_parts([0.0, 0.0, 1.0], [[2.0, 0.0, 0.0]], parts)
    assert t[0] == 2.0
    t, part, _, _ = intersect_parts([0.0, 0.0, 1.0], [[1.0, 0.0, 0.0]], parts, t_max=3.9)
    assert np.isinf(t[0]) and part[0] == -1


def test_ray_starting_inside_a_box_misses_it():
    t, _, _ = intersect_boxes(np.zeros((1, 3)), np.array([[1.0, 0.0, 0.0]]), np.zeros((1, 3)),
                              np.ones((1, 3)), np.zeros(1))
    assert np.isinf(t[0])


def test_ground_plane():
    t = intersect_ground([0.0, 0.0, 2.0], np.array([[1.0, 0.0, -1.0], [1.0, 0.0, 0.5], [1.0, 0, 0]]))
    assert t[0] == 2.0
    assert np.isinf(t[1]) and np.isinf(t[2])
    assert np.isinf(intersect_ground([0.0, 0.0, 2.0], np.array([[1.0, 0.0, -1.0]]), t_max=1.5)[0])


def test_culled_intersection_matches_brute_force():
    rng = np.random.default_rng(3)
    m, r = 60, 3000
    parts = _parts(rng.uniform(-20, 20, (m, 3)), rng.uniform(0.1, 2.0, (m, 3)), rng.uniform(-3, 3, m))
    origin = np.array([0.5, -0.3, 0.2])
    dirs = rng.normal(size=(r, 3))
    dirs = dirs[np.argsort(np.arctan2(dirs[:, 1], dirs[:, 0]))]
    t, part, _, _ = intersect_parts(origin, dirs, parts, t_max=30.0, bundle=64)
    ray = np.repeat(np.arange(r), m)
    pid = np.tile(np.arange(m), r)
    tb, _, _ = intersect_boxes(np.broadcast_to(origin, (r * m, 3)), dirs[ray], parts.center[pid],
                                parts.half_size[pid], parts.yaw[pid], 30.0)
    tb = tb.reshape(r, m)
    np.testing.assert_array_equal(t, tb.min(axis=1))
    hit = np.isfinite(t)
    assert hit.sum() > 100
    np.testing.assert_array_equal(part[hit], tb[hit].argmin(axis=1))
    np.testing.assert_array_equal(part[~hit], -1)
