"""The devkit's range, zero-points and bicycle-rack filters, at their edges."""

from __future__ import annotations

import warnings

import numpy as np

from sianms_cli.metrics.boxes import make_boxes
from sianms_cli.metrics.config import load_config
from sianms_cli.metrics.filters import ego_distance, filter_boxes, in_bicycle_rack
from sianms_cli.geometry.quaternion import yaw_to_quat

EGO = np.array([[100.0, 200.0, 0.0], [-5.0, 3.0, 0.0]])
NO_RACKS = make_boxes(np.zeros(0, int), 0, np.zeros((0, 3)))


def test_ego_distance_is_the_devkits_ego_dist():
    rng = np.random.default_rng(0)
    boxes = make_boxes(rng.integers(0, 2, 500), "car", rng.normal(50, 40, (500, 3)))
    expected = [np.sqrt(np.sum(np.array(tuple(b["translation"] - EGO[b["sample"]])[:2]) ** 2)) for b in boxes]
    assert np.array_equal(ego_distance(boxes, EGO), expected)


def test_a_box_1e200_m_away_is_infinitely_far_without_numpy_warnings():
    boxes = make_boxes(np.array([0]), "car", np.array([[1e200, 1e200, 0.0]]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert ego_distance(boxes, EGO).tolist() == [np.inf]  # out of every range, as in the devkit


def test_range_is_strict_and_per_class():
    config = load_config("detection_cvpr_2019")
    x_at_50 = 100.0 + 50.0
    boxes = make_boxes(0, ["car", "car", "pedestrian", "traffic_cone"],
                       [[x_at_50, 200, 0], [np.nextafter(x_at_50, 0), 200, 0], [139.99, 200, 0], [130.5, 200, 0]])
    result = filter_boxes(boxes, EGO, NO_RACKS, config, ground_truth=False)
    assert result.kept.tolist() == [False, True, True, False]
    assert result.out_of_range == 2


def test_classes_outside_the_config_are_dropped():
    boxes = make_boxes(0, ["car", "truck", "bicycle"], [[101, 200, 0]] * 3)
    kept = filter_boxes(boxes, EGO, NO_RACKS, load_config("paper"), ground_truth=False).kept
    assert kept.tolist() == [True, False, True]


def test_zero_points_drop_ground_truth_only():
    boxes = make_boxes(1, "car", [[-4, 3, 0]] * 3, num_pts=[0, 1, -1])
    config = load_config()
    assert filter_boxes(boxes, EGO, NO_RACKS, config, ground_truth=True).kept.tolist() == [False, True, True]
    predictions = filter_boxes(boxes, EGO, NO_RACKS, config, ground_truth=False)
    assert predictions.kept.all() and predictions.without_points == 0


def test_bicycle_rack_filter_is_inclusive_and_only_for_cycles():
    racks = make_boxes(0, 0, [[110.0, 200.0, 1.0]], size=(2.0, 6.0, 2.0), rotation=yaw_to_quat(np.pi / 2))
    # Rack yawed 90 degrees: its length (6 m) runs along y, its width (2 m) along x.
    centres = [[110.0, 200.0, 1.0], [110.0, 203.0, 1.0], [111.0, 200.0, 1.0], [110.0, 203.5, 1.0], [110.0, 200.0, 1.0],
               [110.0, 200.0, 1.0], [110.0, 200.0, 1.0]]
    boxes = make_boxes([0, 0, 0, 0, 0, 1, 0],
                       ["bicycle", "bicycle", "motorcycle", "bicycle", "car", "bicycle", "pedestrian"], centres)
    inside = in_bicycle_rack(boxes, racks)
    # centre, on the end face, on the side face: inside; beyond the end, a car, another sample, a pedestrian: not.
    assert inside.tolist() == [True, True, True, False, False, False, False]
    result = filter_boxes(boxes, EGO, racks, load_config(), ground_truth=True)
    assert result.in_bicycle_rack == 3
