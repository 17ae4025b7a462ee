import numpy as np
import pytest

from sianms_cli.geometry.clip import (
    clip_to_rectangles,
    convex_hulls,
    hull_in_rectangle,
    hull_meets_rectangle,
    polygon_areas,
)


def _reference_hull(points):
    """Andrew's monotone chain, one point set at a time (counter-clockwise, no collinear points)."""
    points = sorted(set(map(tuple, points)))
    if len(points) < 3:
        return points

    def half(sequence):
        chain = []
        for p in sequence:
            while len(chain) >= 2 and ((chain[-1][0] - chain[-2][0]) * (p[1] - chain[-2][1])
                                       - (chain[-1][1] - chain[-2][1]) * (p[0] - chain[-2][0])) <= 0:
                chain.pop()
            chain.append(p)
        return chain

    lower, upper = half(points), half(reversed(points))
    return lower[:-1] + upper[:-1]


def _reference_clip(polygon, width, height):
    """Textbook Sutherland–Hodgman, one polygon and one edge at a time."""
    for inside in (lambda p: p[0], lambda p: width - p[0], lambda p: p[1], lambda p: height - p[1]):
        out = []
        for i, current in enumerate(polygon):
            following = polygon[(i + 1) % len(polygon)]
            a, b = inside(current), inside(following)
            if a >= 0:
                out.append(current)
            if (a >= 0) != (b >= 0):
                t = a / (a - b)
                out.append((current[0] + t * (following[0] - current[0]), current[1] + t * (following[1] - current[1])))
        polygon = out
        if not polygon:
            break
    return polygon


def _reference(points, keep, width, height):
    """Extent and area of hull(kept points) ∩ [0, W] x [0, H], the slow way."""
    polygon = _reference_clip(_reference_hull([tuple(p) for p, k in zip(points, keep) if k]), width, height)
    if len(polygon) < 3:
        return None, 0.0
    area = 0.5 * sum(p[0] * q[1] - p[1] * q[0] for p, q in zip(polygon, polygon[1:] + polygon[:1]))
    us, vs = [p[0] for p in polygon], [p[1] for p in polygon]
    return (min(us), min(vs), max(us), max(vs)), area


def _one(points, keep=None, width=160.0, height=90.0):
    points = np.asarray(points, dtype=np.float64)[None]
    keep = np.ones(points.shape[:2], dtype=bool) if keep is None else np.asarray(keep)[None]
    extents, areas = hull_in_rectangle(points, keep, width, height)
    return extents[0], areas[0]


def test_a_set_inside_the_image_keeps_its_hull_extent_and_area():
    extent, area = _one([[10, 10], [50, 10], [50, 40], [10, 40], [30, 25], [20, 20]])
    assert extent.tolist() == [10, 10, 50, 40]
    assert area == 1200


def test_a_set_straddling_an_edge_is_cut_at_the_edge():
    extent, area = _one([[-20, 10], [40, 10], [40, 30], [-20, 30]])
    assert extent.tolist() == [0, 10, 40, 30]
    assert area == 800


def test_a_diagonal_hull_across_a_corner_is_clipped_not_its_point_extent():
    # The triangle's points all lie outside the image; only its tip crosses the corner.
    extent, area = _one([[-10, 20], [20, -10], [-40, -40]])
    assert extent.tolist() == [0, 0, 10, 10]
    assert area == pytest.approx(50)


def test_a_hull_holding_the_whole_image_is_the_image():
    extent, area = _one([[-1e6, -1e6], [1e6, -1e6], [0, 1e6]], width=160, height=90)
    assert extent.tolist() == [0, 0, 160, 90]
    assert area == pytest.approx(160 * 90)


def test_outside_or_too_few_or_collinear_points_give_no_area():
    assert _one([[200, 10], [300, 10], [250, 50]])[1] == 0
    assert _one([[10, 10], [50, 40], [0, 0]], keep=[True, True, False])[1] == 0
    assert _one([[10, 10], [20, 20], [30, 30], [40, 40]])[1] == 0
    assert np.isnan(_one([[200, 10], [300, 10], [250, 50]])[0]).all()


def test_dropped_points_do_not_count():
    extent, area = _one([[10, 10], [50, 10], [50, 40], [10, 40], [150, 80]], keep=[1, 1, 1, 1, 0])
    assert extent.tolist() == [10, 10, 50, 40] and area == 1200


def test_repeated_points_and_points_on_the_hull_edges():
    extent, area = _one([[10, 10], [10, 10], [30, 10], [50, 10], [50, 40], [50, 40], [10, 40], [10, 25]])
    assert extent.tolist() == [10, 10, 50, 40] and area == 1200


def test_hulls_are_counter_clockwise_and_hold_only_hull_vertices():
    points = np.array([[[0, 0], [4, 0], [4, 4], [0, 4], [2, 2], [1, 3], [3, 1], [2, 1]]], dtype=float)
    polygons, counts = convex_hulls(points, np.ones((1, 8), dtype=bool))
    assert counts.tolist() == [4]
    assert sorted(map(tuple, polygons[0, :4].tolist())) == [(0, 0), (0, 4), (4, 0), (4, 4)]
    assert polygon_areas(polygons, counts).tolist() == [16.0]


def test_clipping_each_edge_adds_at_most_one_vertex():
    polygons = np.array([[[-10, 45], [80, -10], [170, 45], [80, 100]]], dtype=float)
    clipped, counts = clip_to_rectangles(polygons, np.array([4]), 160.0, 90.0)
    assert clipped.shape == (1, 8, 2) and counts.tolist() == [8]


@pytest.mark.parametrize("seed", range(4))
def test_matches_a_slow_reference_on_random_sets(seed):
    rng = np.random.default_rng(seed)
    n = 400
    # Points around a 160 x 90 image, some far away (corners just in front of a camera).
    points = rng.normal([80, 45], [120, 80], size=(n, 8, 2))
    points[rng.random((n, 8)) < 0.05] *= 1e3
    keep = rng.random((n, 8)) < 0.8
    width = rng.choice([160.0, 90.0], size=n)
    height = np.full(n, 90.0)
    extents, areas = hull_in_rectangle(points, keep, width, height)
    for i in range(n):
        extent, area = _reference(points[i].tolist(), keep[i].tolist(), width[i], height[i])
        assert areas[i] == pytest.approx(area, rel=1e-9, abs=1e-6), i
        if area > 0:
            assert extents[i] == pytest.approx(extent, rel=1e-9, abs=1e-6), i
    assert (areas > 0).sum() > n // 4


def test_empty_sets_and_no_sets():
    extents, areas = hull_in_rectangle(np.zeros((2, 0, 2)), np.zeros((2, 0), dtype=bool), 160.0, 90.0)
    assert areas.tolist() == [0, 0] and np.isnan(extents).all()
    extents, areas = hull_in_rectangle(np.zeros((0, 8, 2)), np.zeros((0, 8), dtype=bool), 160.0, 90.0)
    assert extents.shape == (0, 4) and areas.shape == (0,)


@pytest.mark.parametrize("seed", range(3))
def test_hull_meets_rectangle_is_hull_in_rectangle_with_positive_area(seed):
    rng = np.random.default_rng(seed)
    n = 2000
    points = rng.normal([80, 45], [60, 40], size=(n, 8, 2))
    points[: n // 4] = np.clip(points[: n // 4], 0, [160, 90])  # all inside
    # Exactly collinear sets, inside and crossing (integer steps keep the arithmetic exact).
    steps = rng.integers(-9, 10, size=(n // 8, 1, 2)) * np.arange(8)[None, :, None]
    points[n // 4: n // 4 + n // 8] = rng.integers(0, 90, size=(n // 8, 1, 2)) + steps
    keep = rng.random((n, 8)) < 0.85
    expected = hull_in_rectangle(points, keep, 160.0, 90.0)[1] > 0
    assert np.array_equal(hull_meets_rectangle(points, keep, 160.0, 90.0), expected)
    assert 0 < expected.sum() < n
    assert not hull_meets_rectangle(np.array([[[10, 10], [20, 20], [40, 40]]], dtype=float),
                                    np.ones((1, 3), dtype=bool), 160.0, 90.0)[0]
