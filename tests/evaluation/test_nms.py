"""evaluation/nms.py: hand-made kept sets, the threshold's edge, and a brute-force greedy reference."""

import math

import numpy as np
import pytest

from sianms_cli.errors import SianmsError
from sianms_cli.geometry.bev import AXIS_MODES, axis_iou_matrix, rotated_iou_matrix
from sianms_cli.evaluation.nms import CIRCLE_RADIUS_M, axis_nms, circle_nms, rotated_nms


def boxes(*rows):
    """(centers, sizes, yaw) of rows (x, y, width, length, yaw)."""
    array = np.array(rows, dtype=float)
    return array[:, :2], array[:, 2:4], array[:, 4]


def greedy_reference(suppresses, scores):
    """The definition: visit by score (ties: lower index), keep a box no kept box suppresses."""
    kept = []
    for i in sorted(range(len(scores)), key=lambda i: (-scores[i], i)):
        if not any(suppresses[k, i] for k in kept):
            kept.append(i)
    return np.array(kept, dtype=np.int64)


def duplicated_cars(rng, cars, labels=3, area=30.0):
    """Cars detected 1 + Poisson(2) times with jitter; scores on a 0.05 grid, so ties occur."""
    copies = 1 + rng.poisson(2, cars)
    center = np.repeat(rng.uniform(0, area, (cars, 2)), copies, axis=0)
    size = np.repeat(np.array([1.9, 4.6]) * rng.uniform(0.9, 1.1, (cars, 2)), copies, axis=0)
    yaw = np.repeat(rng.uniform(-np.pi, np.pi, cars), copies)
    count = len(center)
    center = center + rng.normal(0, 0.3, (count, 2))
    yaw = yaw + rng.normal(0, 0.1, count)
    return center, size, yaw, np.round(rng.uniform(0, 1, count) * 20) / 20, rng.integers(0, labels, count)


# A: 3 m long at the origin. B: shifted 1 m along x (IoU 2/4 = 0.5 with A, exactly).
# C: far away. D: a copy of A of another class.
CENTERS, SIZES, YAW = boxes((0, 0, 1, 3, 0), (1, 0, 1, 3, 0), (20, 20, 2, 4, 1.0), (0, 0, 1, 3, 0))
LABELS = np.array([0, 0, 0, 1])


@pytest.mark.parametrize("threshold, kept", [(0.5, [2, 1, 3, 0]), (0.49, [2, 1, 3])])
def test_rotated_threshold_is_strict_and_classes_do_not_suppress(threshold, kept):
    scores = np.array([0.5, 0.8, 0.9, 0.6])
    bev = np.column_stack([CENTERS, SIZES, YAW])
    assert rotated_iou_matrix(bev[:2], bev[:2])[0, 1] == 0.5  # A and B sit exactly on the edge
    result = rotated_nms(CENTERS, SIZES, YAW, scores, LABELS, threshold)
    assert result.dtype == np.int64 and result.tolist() == kept


@pytest.mark.parametrize("mode", AXIS_MODES)
@pytest.mark.parametrize("threshold, kept", [(0.5, [2, 1, 3, 0]), (0.49, [2, 1, 3])])
def test_axis_threshold_is_strict_in_every_mode(mode, threshold, kept):
    scores = np.array([0.5, 0.8, 0.9, 0.6])
    assert axis_nms(CENTERS, SIZES, YAW, scores, LABELS, threshold, mode=mode).tolist() == kept


def test_equal_scores_keep_the_lower_index():
    centers, sizes, yaw = boxes((0, 0, 2, 4, 0.2), (0.1, 0, 2, 4, 0.2), (0.2, 0, 2, 4, 0.25))
    scores, labels = np.full(3, 0.7), np.zeros(3, dtype=int)
    assert rotated_nms(centers, sizes, yaw, scores, labels, 0.3).tolist() == [0]
    assert axis_nms(centers, sizes, yaw, scores, labels, 0.3).tolist() == [0]
    assert circle_nms(centers, scores, labels, 1.0).tolist() == [0]
    assert rotated_nms(centers[::-1], sizes[::-1], yaw[::-1], scores, labels, 0.3).tolist() == [0]


def test_axis_modes_differ_on_crossed_boxes():
    # The same 1 x 4 box along x and along y: ignore-yaw sees one rectangle (IoU 1),
    # nearest-bev and enclosing see a cross (IoU 1/7 < 0.3).
    centers, sizes, yaw = boxes((0, 0, 1, 4, 0.0), (0, 0, 1, 4, np.pi / 2))
    scores, labels = np.array([0.9, 0.8]), np.zeros(2, dtype=int)
    assert axis_nms(centers, sizes, yaw, scores, labels, 0.3, mode="ignore-yaw").tolist() == [0]
    assert axis_nms(centers, sizes, yaw, scores, labels, 0.3, mode="nearest-bev").tolist() == [0, 1]
    assert axis_nms(centers, sizes, yaw, scores, labels, 0.3, mode="enclosing").tolist() == [0, 1]
    assert rotated_nms(centers, sizes, yaw, scores, labels, 0.3).tolist() == [0, 1]


def test_a_chain_keeps_the_box_its_suppressor_lost():
    # 0 suppresses 1, 1 would suppress 2, but 1 is gone, so 2 stays (greedy, not clustering).
    centers, sizes, yaw = boxes((0, 0, 1, 3, 0), (1, 0, 1, 3, 0), (2, 0, 1, 3, 0))
    kept = rotated_nms(centers, sizes, yaw, np.array([0.9, 0.8, 0.7]), np.zeros(3, dtype=int), 0.3)
    assert kept.tolist() == [0, 2]


def test_zero_area_boxes_neither_suppress_nor_are_suppressed():
    centers, sizes, yaw = boxes((0, 0, 2, 4, 0.3), (0, 0, 0, 0, 0.0), (0, 0, 0, 4, 0.3))
    kept = rotated_nms(centers, sizes, yaw, np.array([0.5, 0.9, 0.7]), np.zeros(3, dtype=int), 0.0)
    assert kept.tolist() == [1, 2, 0]


def test_global_coordinates_give_the_same_kept_set():
    rng = np.random.default_rng(11)
    centers, sizes, yaw, scores, labels = duplicated_cars(rng, 40)
    local = rotated_nms(centers, sizes, yaw, scores, labels, 0.2)
    far = rotated_nms(centers + [1834.25, 912.5], sizes, yaw, scores, labels, 0.2)
    assert np.array_equal(local, far)


@pytest.mark.parametrize("seed", range(6))
def test_rotated_nms_equals_the_brute_force_greedy(seed):
    rng = np.random.default_rng(seed)
    centers, sizes, yaw, scores, labels = duplicated_cars(rng, 40)
    bev = np.column_stack([centers, sizes, yaw])
    iou = rotated_iou_matrix(bev, bev)
    for threshold in (0.0, 0.1, 0.3, 0.7):
        suppresses = (iou > threshold) & (labels[:, None] == labels[None])
        expected = greedy_reference(suppresses, scores)
        assert np.array_equal(rotated_nms(centers, sizes, yaw, scores, labels, threshold), expected)
        assert 0 < len(expected) < len(scores)


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("mode", AXIS_MODES)
def test_axis_nms_equals_the_brute_force_greedy(seed, mode):
    rng = np.random.default_rng(100 + seed)
    centers, sizes, yaw, scores, labels = duplicated_cars(rng, 40)
    bev = np.column_stack([centers, sizes, yaw])
    suppresses = (axis_iou_matrix(bev, bev, mode) > 0.3) & (labels[:, None] == labels[None])
    assert np.array_equal(axis_nms(centers, sizes, yaw, scores, labels, 0.3, mode=mode),
                          greedy_reference(suppresses, scores))


def test_circle_nms_hand_case_in_metres():
    # Car radius 2.0 m: box 1, 2.0 m away, is suppressed (<=, as CenterPoint's comparison);
    # box 2, 2.01 m away, is not; box 3, of another class, is not either.
    centers = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.01], [0.0, 0.0]])
    scores, labels = np.array([0.9, 0.8, 0.7, 0.6]), np.array([0, 0, 0, 1])
    assert circle_nms(centers, scores, labels, CIRCLE_RADIUS_M["car"]).tolist() == [0, 2, 3]
    # CenterPoint's raw "4" taken as metres would also take box 2: the squared-distance trap.
    assert circle_nms(centers, scores, labels, 4.0).tolist() == [0, 3]
    # One radius per box: the kept box's own radius decides.
    assert circle_nms(centers, scores, labels, np.array([1.0, 2.0, 2.0, 2.0])).tolist() == [0, 1, 2, 3]


def test_circle_radii_are_centerpoints_squared_thresholds_rooted():
    assert CIRCLE_RADIUS_M["car"] == 2.0
    assert CIRCLE_RADIUS_M["pedestrian"] == pytest.approx(math.sqrt(0.175))
    assert CIRCLE_RADIUS_M["bicycle"] == pytest.approx(0.922, abs=1e-3)
    assert CIRCLE_RADIUS_M["truck"] == pytest.approx(3.464, abs=1e-3)
    assert len(CIRCLE_RADIUS_M) == 10


@pytest.mark.parametrize("seed", range(3))
def test_circle_nms_equals_the_brute_force_greedy(seed):
    rng = np.random.default_rng(200 + seed)
    centers, _, _, scores, labels = duplicated_cars(rng, 40)
    radius = rng.uniform(0.5, 2.5, len(scores))
    distance = np.linalg.norm(centers[:, None] - centers[None], axis=2)
    suppresses = (distance <= radius[:, None]) & (labels[:, None] == labels[None])
    assert np.array_equal(circle_nms(centers, scores, labels, radius), greedy_reference(suppresses, scores))


def test_empty_input_keeps_nothing():
    empty = np.zeros((0, 2))
    assert rotated_nms(empty, empty, np.zeros(0), np.zeros(0), np.zeros(0), 0.3).dtype == np.int64
    assert axis_nms(empty, empty, np.zeros(0), np.zeros(0), np.zeros(0), 0.3).size == 0
    assert circle_nms(empty, np.zeros(0), np.zeros(0), 2.0).size == 0


def test_bad_arguments_raise_sianms_error():
    scores = np.array([0.5, 0.8, 0.9, 0.6])
    with pytest.raises(SianmsError, match=r"in \[0, 1\]"):
        rotated_nms(CENTERS, SIZES, YAW, scores, LABELS, 1.5)
    with pytest.raises(SianmsError, match=r"in \[0, 1\]"):
        axis_nms(CENTERS, SIZES, YAW, scores, LABELS, -0.1)
    with pytest.raises(SianmsError, match="unknown axis-aligned BEV mode"):
        axis_nms(CENTERS, SIZES, YAW, scores, LABELS, 0.3, mode="rotated")
    with pytest.raises(SianmsError, match="one score and one label"):
        rotated_nms(CENTERS, SIZES, YAW, scores[:3], LABELS, 0.3)
    with pytest.raises(SianmsError, match="finite"):
        rotated_nms(CENTERS, SIZES, YAW, np.array([0.5, np.nan, 0.9, 0.6]), LABELS, 0.3)
    with pytest.raises(SianmsError, match="radius"):
        circle_nms(CENTERS, scores, LABELS, -1.0)
    with pytest.raises(SianmsError, match="radius"):
        circle_nms(CENTERS, scores, LABELS, np.ones(3))
