"""Duplicates left after duplicate handling, counted with the devkit's greedy matching."""

import numpy as np

from sianms_cli.metrics.boxes import LABEL, empty_boxes
from sianms_cli.evaluation.scoring import duplicates, near_ground_truth


def boxes(rows):
    """Box table of (sample, class, x, y, score) rows."""
    table = empty_boxes(len(rows))
    for i, (sample, name, x, y, score) in enumerate(rows):
        table[i]["sample"], table[i]["label"], table[i]["score"] = sample, LABEL[name], score
        table[i]["translation"] = (x, y, 0.0)
    return table


def test_near_ground_truth_looks_only_in_the_same_sample():
    near = near_ground_truth(np.array([1, 0, 1]), np.array([[0.0, 0.0], [10.0, 0.0], [5.0, 5.0]]),
                             np.array([0, 0, 1, 2]), np.array([[0.5, 0.0], [10.5, 0.0], [5.0, 6.9], [0.0, 0.0]]), 2.0)
    assert near.tolist() == [False, True, True, False]


def test_a_second_prediction_on_a_taken_box_is_a_duplicate_a_far_one_is_not():
    gt = boxes([(0, "car", 0.0, 0.0, -1), (0, "car", 20.0, 0.0, -1), (1, "car", 0.0, 0.0, -1)])
    pred = boxes([(0, "car", 0.2, 0.0, 0.9),    # takes GT 0
                  (0, "car", -0.3, 0.5, 0.8),   # GT 0 already taken: a duplicate
                  (0, "car", 10.0, 0.0, 0.7),   # nowhere near a box: a plain false positive
                  (0, "car", 19.0, 0.5, 0.6),   # takes GT 1
                  (1, "car", 1.9, 0.0, 0.5),    # takes the other sample's GT
                  (1, "pedestrian", 0.0, 0.0, 0.9)])  # another class
    assert duplicates(gt, pred, "car", 2.0) == 1
    assert duplicates(gt, pred, "pedestrian", 2.0) == 0
    assert duplicates(gt, boxes([(0, "car", 0.0, 0.0, 0.5)] * 3), "car", 2.0) == 2
