import numpy as np
import pytest

from sianms_cli.detection2d.association import associate, box_iou
from sianms_cli.errors import SianmsError


def test_iou_values():
    a = np.array([[0, 0, 10, 10]])
    b = np.array([[5, 0, 15, 10], [20, 20, 30, 30], [0, 0, 10, 10]])
    assert box_iou(a, b)[0].tolist() == pytest.approx([50 / 150, 0.0, 1.0])


def test_optimal_not_greedy():
    # Detection 0 overlaps both GT boxes (0.67 with GT 0, 0.43 with GT 1); detection 1 only GT 0
    # (0.82). Greedy in detection order gives det0-GT0 and leaves det1 unmatched; the optimal
    # assignment gives det0-GT1, det1-GT0.
    gt = np.array([[0, 0, 10, 10], [6, 0, 16, 10]], dtype=float)
    det = np.array([[2, 0, 12, 10], [-1, 0, 9, 10]], dtype=float)
    match, iou = associate(det, gt, 0.3)
    assert match.tolist() == [1, 0]
    assert iou.tolist() == pytest.approx([box_iou(det[:1], gt[1:])[0, 0], box_iou(det[1:], gt[:1])[0, 0]])


def test_threshold_edge_is_inclusive():
    gt = np.array([[0, 0, 10, 10]], dtype=float)
    det = np.array([[0, 0, 10, 5]], dtype=float)  # IoU exactly 0.5
    assert associate(det, gt, 0.5)[0].tolist() == [0]
    assert associate(det, gt, 0.5 + 1e-9)[0].tolist() == [-1]


def test_classes_must_agree_and_no_double_claims():
    gt = np.array([[0, 0, 10, 10]], dtype=float)
    det = np.array([[0, 0, 10, 10], [0, 0, 10, 9]], dtype=float)
    match, _ = associate(det, gt, 0.5, np.array(["pedestrian", "car"]), np.array(["car"]))
    assert match.tolist() == [-1, 0]
    match, _ = associate(det, gt, 0.5)
    assert sorted(match.tolist()) == [-1, 0]


def test_empty_inputs_and_bad_threshold():
    assert associate(np.zeros((0, 4)), np.zeros((3, 4)))[0].shape == (0,)
    assert associate(np.ones((2, 4)) * [0, 0, 1, 1], np.zeros((0, 4)))[0].tolist() == [-1, -1]
    with pytest.raises(SianmsError, match="threshold"):
        associate(np.zeros((1, 4)), np.zeros((1, 4)), 0.0)
