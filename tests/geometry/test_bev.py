"""geometry/bev.py: rotated IoU against shapely polygons, hand cases, the three axis-aligned modes."""

import subprocess
import sys
import warnings

import numpy as np
import pytest
import shapely

from sianms_cli.errors import SianmsError
from sianms_cli.geometry.bev import (
    AXIS_MODES,
    axis_aligned_rectangles,
    axis_iou_matrix,
    axis_iou_pairs,
    bev_corners,
    rotated_intersection_areas,
    rotated_iou_matrix,
    rotated_iou_pairs,
)


def box(x, y, width, length, yaw):
    """One (1, 5) BEV box."""
    return np.array([[x, y, width, length, yaw]], dtype=float)


def shapely_iou(boxes_a, boxes_b):
    """Rotated IoU of row pairs from shapely polygon areas (the slow, obvious reference)."""
    corners_a = bev_corners(boxes_a[:, :2], boxes_a[:, 2:4], boxes_a[:, 4])
    corners_b = bev_corners(boxes_b[:, :2], boxes_b[:, 2:4], boxes_b[:, 4])
    polygons_a, polygons_b = shapely.polygons(corners_a), shapely.polygons(corners_b)
    intersection = shapely.area(shapely.intersection(polygons_a, polygons_b))
    union = shapely.area(polygons_a) + shapely.area(polygons_b) - intersection
    return intersection / np.maximum(union, 1e-8)


def random_boxes(rng, count, offset=0.0):
    return np.column_stack([rng.uniform(-3, 3, (count, 2)) + offset, rng.uniform(0.2, 5, (count, 2)),
                            rng.uniform(-4, 4, count)])


def test_corners_follow_the_nuscenes_yaw_and_run_counter_clockwise():
    # Yaw pi/2 turns the length axis from +x to +y; the first corner is front-left.
    corners = bev_corners(np.zeros((1, 2)), np.array([[2.0, 4.0]]), np.array([np.pi / 2]))[0]
    assert np.allclose(corners, [[-1, 2], [-1, -2], [1, -2], [1, 2]])
    shifted = np.roll(corners, -1, axis=0)
    assert 0.5 * np.sum(corners[:, 0] * shifted[:, 1] - corners[:, 1] * shifted[:, 0]) == pytest.approx(8.0)


@pytest.mark.parametrize("offset", [0.0, 1500.0])
def test_rotated_iou_matches_shapely_on_random_pairs(offset):
    rng = np.random.default_rng(7)
    a, b = random_boxes(rng, 3000, offset), random_boxes(rng, 3000, offset)
    # Near-copies too: small shifts and turns make the many-vertex intersections.
    near = a + np.column_stack([rng.normal(0, 0.2, (3000, 2)), np.zeros((3000, 2)), rng.normal(0, 0.2, 3000)])
    for other in (b, near):
        iou = rotated_iou_pairs(a, other)
        assert np.abs(iou - shapely_iou(a, other)).max() < 1e-9
    assert (rotated_iou_pairs(a, b) > 0).mean() > 0.3  # the sample does exercise overlaps


def test_rotated_iou_matrix_is_every_pair():
    rng = np.random.default_rng(1)
    a, b = random_boxes(rng, 7), random_boxes(rng, 5)
    matrix = rotated_iou_matrix(a, b)
    assert matrix.shape == (7, 5)
    assert np.array_equal(matrix, rotated_iou_pairs(np.repeat(a, 5, axis=0), np.tile(b, (7, 1))).reshape(7, 5))


@pytest.mark.parametrize("yaw", [0.0, 0.3, np.pi / 2, -2.5])
def test_identical_boxes_have_iou_one(yaw):
    a = box(10.0, -4.0, 1.9, 4.6, yaw)
    assert rotated_iou_pairs(a, a)[0] == pytest.approx(1.0, abs=1e-12)
    assert rotated_iou_pairs(a, box(10.0, -4.0, 1.9, 4.6, yaw + np.pi))[0] == pytest.approx(1.0, abs=1e-12)


def test_hand_cases():
    a = box(0.0, 0.0, 2.0, 4.0, 0.0)
    # Touching along an edge, rotated together: no area in common.
    turn = 0.6
    touching = box(4.0 * np.cos(turn), 4.0 * np.sin(turn), 2.0, 4.0, turn)
    assert rotated_iou_pairs(box(0, 0, 2, 4, turn), touching)[0] == pytest.approx(0.0, abs=1e-12)
    assert rotated_iou_pairs(a, box(4.0, 0.0, 2.0, 4.0, 0.0))[0] == 0.0
    # Nested: the small box lies inside, so IoU = its area / the big one's.
    assert rotated_iou_pairs(a, box(0.5, 0.2, 0.5, 1.0, 0.7))[0] == pytest.approx(0.5 / 8.0, abs=1e-12)
    # Disjoint.
    assert rotated_iou_pairs(a, box(10.0, 10.0, 2.0, 4.0, 1.0))[0] == 0.0
    # Crossed at 90 degrees about the same centre: a 2 x 2 square in common, union 8 + 8 - 4.
    assert rotated_iou_pairs(a, box(0.0, 0.0, 2.0, 4.0, np.pi / 2))[0] == pytest.approx(4.0 / 12.0, abs=1e-12)
    # A square and its 45-degree turn meet in a regular octagon.
    octagon = 8 * (np.sqrt(2) - 1)
    square, turned = box(0, 0, 2, 2, 0.0), box(0, 0, 2, 2, np.pi / 4)
    assert rotated_iou_pairs(square, turned)[0] == pytest.approx(octagon / (8 - octagon), abs=1e-12)


def test_degenerate_boxes_give_zero_without_warnings():
    a = box(0.0, 0.0, 2.0, 4.0, 0.3)
    degenerate = np.concatenate([box(0, 0, 0, 0, 0), box(0, 0, 0, 3, 0.2), box(0.1, 0, 1, 0, 1.0)])
    with warnings.catch_warnings(), np.errstate(all="raise"):
        warnings.simplefilter("error")
        iou = rotated_iou_pairs(np.repeat(a, 3, axis=0), degenerate)
        self_iou = rotated_iou_pairs(degenerate, degenerate)
        area = rotated_intersection_areas(bev_corners(degenerate[:, :2], degenerate[:, 2:4], degenerate[:, 4]),
                                          bev_corners(degenerate[:, :2], degenerate[:, 2:4], degenerate[:, 4]))
        axis = axis_iou_pairs(degenerate, degenerate, "ignore-yaw")
    assert np.array_equal(iou, np.zeros(3)) and np.array_equal(self_iou, np.zeros(3))
    assert np.array_equal(area, np.zeros(3)) and np.array_equal(axis, np.zeros(3))
    # The enclosing rectangle of a turned segment does have an area.
    assert axis_iou_pairs(degenerate[1:2], degenerate[1:2], "enclosing")[0] == pytest.approx(1.0)


def test_axis_aligned_modes_hand_cases():
    along_x = box(0.0, 0.0, 1.0, 4.0, 0.0)
    along_y = box(0.0, 0.0, 1.0, 4.0, np.pi / 2)
    # ignore-yaw: both become 4 (x) by 1 (y); nearest-bev and enclosing turn the second.
    assert axis_iou_pairs(along_x, along_y, "ignore-yaw")[0] == 1.0
    assert axis_iou_pairs(along_x, along_y, "nearest-bev")[0] == pytest.approx(1 / 7, abs=1e-12)
    assert axis_iou_pairs(along_x, along_y, "enclosing")[0] == pytest.approx(1 / 7, abs=1e-12)
    # A 2 m square turned 45 degrees: its enclosing box is 2 sqrt 2 wide (area 8).
    square, turned = box(0, 0, 2, 2, 0.0), box(0, 0, 2, 2, np.pi / 4)
    assert axis_iou_pairs(square, turned, "ignore-yaw")[0] == 1.0
    assert axis_iou_pairs(square, turned, "nearest-bev")[0] == 1.0
    assert axis_iou_pairs(square, turned, "enclosing")[0] == pytest.approx(0.5, abs=1e-12)
    # Shifted 1 m along x, 3 m long: 2 m of 3 in common, IoU 2 / 4.
    assert axis_iou_pairs(box(0, 0, 1, 3, 0), box(1, 0, 1, 3, 0), "ignore-yaw")[0] == 0.5


@pytest.mark.parametrize("yaw, swapped", [(0.7, False), (0.9, True), (2.5, False), (-2.0, True), (np.pi, False),
                                          (-np.pi / 2, True)])
def test_nearest_bev_swaps_beyond_45_degrees_of_yaw_wrapped_to_half_turns(yaw, swapped):
    rectangle = axis_aligned_rectangles(np.array([[1.0, 2.0]]), np.array([[1.0, 4.0]]), np.array([yaw]),
                                        "nearest-bev")[0]
    extent = (1.0, 4.0) if swapped else (4.0, 1.0)
    assert np.allclose(rectangle, [1.0 - extent[0] / 2, 2.0 - extent[1] / 2, 1.0 + extent[0] / 2, 2.0 + extent[1] / 2])


def test_enclosing_rectangle_holds_the_rotated_corners():
    rng = np.random.default_rng(3)
    boxes = random_boxes(rng, 50)
    rectangles = axis_aligned_rectangles(boxes[:, :2], boxes[:, 2:4], boxes[:, 4], "enclosing")
    corners = bev_corners(boxes[:, :2], boxes[:, 2:4], boxes[:, 4])
    assert np.abs(rectangles[:, :2] - corners.min(axis=1)).max() < 1e-12
    assert np.abs(rectangles[:, 2:] - corners.max(axis=1)).max() < 1e-12


@pytest.mark.parametrize("mode", AXIS_MODES)
def test_axis_iou_matrix_is_every_pair(mode):
    rng = np.random.default_rng(2)
    a, b = random_boxes(rng, 6), random_boxes(rng, 4)
    matrix = axis_iou_matrix(a, b, mode)
    assert np.array_equal(matrix, axis_iou_pairs(np.repeat(a, 4, axis=0), np.tile(b, (6, 1)), mode).reshape(6, 4))


def test_bad_arguments_raise_sianms_error():
    a = box(0, 0, 1, 2, 0)
    with pytest.raises(SianmsError, match="unknown axis-aligned BEV mode"):
        axis_iou_pairs(a, a, "rotated")
    with pytest.raises(SianmsError, match=r"\(N, 5\)"):
        rotated_iou_pairs(a[:, :4], a[:, :4])
    with pytest.raises(SianmsError, match="as many boxes"):
        rotated_iou_pairs(a, np.repeat(a, 2, axis=0))
    with pytest.raises(SianmsError, match=">= 0"):
        rotated_iou_pairs(box(0, 0, -1, 2, 0), a)
    with pytest.raises(SianmsError, match="finite"):
        bev_corners(np.array([[np.nan, 0.0]]), np.ones((1, 2)), np.zeros(1))


def test_geometry_does_not_import_numba():
    code = "import sys, sianms_cli.geometry.bev; assert 'numba' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)
