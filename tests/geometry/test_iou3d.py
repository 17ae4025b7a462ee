"""geometry/iou3d.py: hand cases and a Monte-Carlo reference on random oriented boxes."""

import numpy as np
import pytest

from sianms_cli.geometry.iou3d import bev_corners, box_iou3d, rotated_intersection_area


def one(center, lwh, heading):
    return np.array([center], float), np.array([lwh], float), np.array([heading], float)


def test_identical_boxes_have_iou_one_and_heading_flip_changes_nothing():
    box = one([1.0, 0.5, 20.0], [4.0, 2.0, 1.5], 0.3)
    flipped = one([1.0, 0.5, 20.0], [4.0, 2.0, 1.5], 0.3 + np.pi)
    assert box_iou3d(*box, *box)[0] == pytest.approx(1.0, abs=1e-12)
    assert box_iou3d(*box, *flipped)[0] == pytest.approx(1.0, abs=1e-12)


def test_shifted_cubes_hand_computed():
    # Two 2 m cubes, 1 m apart along x: intersection 1 x 2 x 2 = 4, union 8 + 8 - 4 = 12.
    a, b = one([0, 0, 10], [2, 2, 2], 0.0), one([1, 0, 10], [2, 2, 2], 0.0)
    assert box_iou3d(*a, *b)[0] == pytest.approx(1 / 3, abs=1e-12)
    # ... and 1 m apart in height as well: intersection 1 x 1 x 2 = 2, union 14.
    c = one([1, 1, 10], [2, 2, 2], 0.0)
    assert box_iou3d(*a, *c)[0] == pytest.approx(2 / 14, abs=1e-12)


def test_square_and_its_45_degree_turn_meet_in_a_regular_octagon():
    a, b = one([0, 0, 0], [2, 2, 1], 0.0), one([0, 0, 0], [2, 2, 1], np.pi / 4)
    octagon = 8 * (np.sqrt(2) - 1)
    area = rotated_intersection_area(bev_corners(*a), bev_corners(*b))[0]
    assert area == pytest.approx(octagon, abs=1e-12)
    assert box_iou3d(*a, *b)[0] == pytest.approx(octagon / (8 - octagon), abs=1e-12)


def test_disjoint_touching_and_zero_size_boxes_give_zero():
    a = one([0, 0, 0], [2, 2, 2], 0.0)
    assert box_iou3d(*a, *one([5, 0, 0], [2, 2, 2], 0.7))[0] == 0.0
    assert box_iou3d(*a, *one([2, 0, 0], [2, 2, 2], 0.0))[0] == pytest.approx(0.0, abs=1e-12)
    assert box_iou3d(*a, *one([0, 0, 0], [0, 0, 0], 0.0))[0] == 0.0


def test_heading_follows_the_fpointnets_convention():
    # Heading pi/2 turns the length axis from +x to (cos, -sin) = (0, -1): along -z.
    corners = bev_corners(*one([0, 0, 0], [4, 2, 1], np.pi / 2))[0]
    assert np.ptp(corners[:, 0]) == pytest.approx(2.0) and np.ptp(corners[:, 1]) == pytest.approx(4.0)


def monte_carlo_iou(ca, sa, ha, cb, sb, hb, rng, samples=400_000):
    """Fraction of uniform samples of the two boxes' bounding region inside both / either."""
    def inside(points, center, lwh, heading):
        offset = points - center
        c, s = np.cos(heading), np.sin(heading)
        along = offset[:, 0] * c - offset[:, 2] * s  # projection on (cos h, 0, -sin h)
        across = offset[:, 0] * s + offset[:, 2] * c  # on (sin h, 0, cos h)
        return (np.abs(along) <= lwh[0] / 2) & (np.abs(across) <= lwh[1] / 2) & (np.abs(offset[:, 1]) <= lwh[2] / 2)

    reach = max(np.linalg.norm(sa), np.linalg.norm(sb)) / 2
    low = np.minimum(ca, cb) - reach
    high = np.maximum(ca, cb) + reach
    points = rng.uniform(low, high, size=(samples, 3))
    in_a, in_b = inside(points, ca, sa, ha), inside(points, cb, sb, hb)
    return (in_a & in_b).sum() / max((in_a | in_b).sum(), 1)


def test_random_pairs_agree_with_monte_carlo():
    rng = np.random.default_rng(0)
    n = 12
    ca = rng.uniform(-1, 1, (n, 3))
    sa = rng.uniform(0.5, 4, (n, 3))
    ha = rng.uniform(-np.pi, np.pi, n)
    cb = ca + rng.normal(0, 0.6, (n, 3))
    sb = sa * rng.uniform(0.7, 1.3, (n, 3))
    hb = ha + rng.normal(0, 0.5, n)
    exact = box_iou3d(ca, sa, ha, cb, sb, hb)
    reference = np.array([monte_carlo_iou(ca[i], sa[i], ha[i], cb[i], sb[i], hb[i], rng) for i in range(n)])
    assert (exact > 0.05).sum() >= 6  # the case set really overlaps
    np.testing.assert_allclose(exact, reference, atol=0.01)
