"""siaNMS matching: candidate bands, forbidden pairs, the optimal assignment, the oracle, pair quality."""

import math

import numpy as np
import pytest

from sianms_cli.geometry.frustum import rotate_to_frustum
from sianms_cli.geometry.camera_ring import CameraRig
from sianms_cli.evaluation.matching import (
    allowed_pairs,
    assign,
    in_columns,
    oracle_matches,
    overlap_columns,
    pair_distances,
    pair_quality,
)
from sianms_cli.evaluation.scene import SceneEvaluator

K = np.array([[100.0, 0.0, 100.0], [0.0, 100.0, 50.0], [0.0, 0.0, 1.0]])  # 200 x 100 image, 90° HFOV


def test_overlap_columns_of_two_cameras_sixty_degrees_apart():
    # b looks 60° right of a; both see 45° either side: a's columns at 15°-45° right are b's too.
    rotation_a_to_b = rotate_to_frustum(np.eye(3), math.radians(60.0)).T
    span = overlap_columns(K, (200, 100), rotation_a_to_b, K, (200, 100))
    assert span[0] == pytest.approx(100 + 100 * math.tan(math.radians(15.0)), abs=1.0)
    assert span[1] == 200.0
    back = overlap_columns(K, (200, 100), rotation_a_to_b.T, K, (200, 100))
    assert back[0] == 0.0 and back[1] == pytest.approx(100 - 100 * math.tan(math.radians(15.0)), abs=1.0)
    opposite = overlap_columns(K, (200, 100), rotate_to_frustum(np.eye(3), math.pi).T, K, (200, 100))
    assert opposite is None
    boxes = np.array([[0, 0, 120, 10], [120, 0, 130, 10], [150, 0, 199, 10]], dtype=float)
    assert in_columns(boxes, span).tolist() == [False, True, True]
    assert in_columns(boxes, None).tolist() == [False, False, False]


def test_the_evaluators_bands_follow_each_rig_it_is_given():
    """Every scene builds its own rigs, numbered from 0: the cached bands are each rig's own (they
    were once keyed by that number, and a later scene got an earlier scene's calibration)."""
    def rig(yaw_b):
        cam_to_ego = np.array([np.eye(4), np.eye(4)])
        cam_to_ego[:, :3, :3] = [rotate_to_frustum(np.eye(3), 0.0), rotate_to_frustum(np.eye(3), math.radians(yaw_b))]
        return CameraRig.from_cameras(["CAM_A", "CAM_B"], np.stack([K, K]), cam_to_ego, [[200, 100], [200, 100]])

    evaluator = SceneEvaluator(None, None, None, None)
    rigs = [rig(yaw_b) for yaw_b in (60.0, 70.0, 60.0)]
    for each in rigs:
        a, b = (0, 1) if each.channels[0] == "CAM_A" else (1, 0)
        rotation = each.ego_to_cam[b, :3, :3] @ each.cam_to_ego[a, :3, :3]
        assert evaluator.span(each, a, b) == overlap_columns(K, (200, 100), rotation, K, (200, 100))


def test_pair_distances_are_l2():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(4, 7)), rng.normal(size=(3, 7))
    expected = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    np.testing.assert_allclose(pair_distances(a, b), expected, atol=1e-12)


def test_allowed_pairs_threshold_class_and_matched_classes():
    distance = np.array([[0.5, 0.5], [0.5, 2.0]])
    allowed = allowed_pairs(distance, ["car", "pedestrian"], ["car", "pedestrian"], 1.0, ("car",))
    assert allowed.tolist() == [[True, False], [False, False]]
    both = allowed_pairs(distance, ["car", "pedestrian"], ["car", "pedestrian"], 1.0, ("car", "pedestrian"))
    assert both.tolist() == [[True, False], [False, False]]
    assert allowed_pairs(distance, ["car", "car"], ["car", "car"], 1.0, ("car",)).tolist() == [[True, True],
                                                                                                [True, False]]


def test_assign_is_optimal_and_never_matches_a_forbidden_pair():
    cost = np.array([[1.0, 2.0], [0.5, 10.0]])
    rows, cols = assign(cost, np.ones((2, 2), bool))
    assert list(zip(rows, cols)) == [(0, 1), (1, 0)]  # 2.5 beats 11
    rows, cols = assign(cost, np.array([[True, False], [True, True]]))
    assert list(zip(rows, cols)) == [(0, 0), (1, 1)]  # two allowed matches beat one cheaper one
    rows, cols = assign(cost, np.array([[False, False], [True, False]]))
    assert list(zip(rows, cols)) == [(1, 0)]
    rows, cols = assign(cost, np.zeros((2, 2), bool))
    assert len(rows) == len(cols) == 0
    rows, cols = assign(np.array([[3.0, 1.0, 2.0]]), np.array([[True, True, True]]))
    assert list(zip(rows, cols)) == [(0, 1)]


def test_oracle_matches_are_the_ground_truth_pairs():
    rows, cols = oracle_matches(np.array(["x", "y", ""]), np.array(["y", "", "x", "z"]),
                                np.array(["car"] * 3), np.array(["car"] * 4), ("car",))
    assert list(zip(rows, cols)) == [(0, 2), (1, 0)]
    rows, _ = oracle_matches(np.array(["x"]), np.array(["x"]), np.array(["pedestrian"]), np.array(["pedestrian"]),
                             ("car",))
    assert len(rows) == 0


def test_pair_quality_figures():
    assert pair_quality(4, 3, 6) == {"pairs_matched": 4, "pairs_correct": 3, "pairs_true": 6, "precision": 0.75,
                                     "recall": 0.5, "f1": 0.6}
    assert pair_quality(0, 0, 0)["precision"] is None
