import numpy as np
import pytest

from sianms_cli.detection2d.ground_truth import camera_ground_truth, occlusion_fractions

K = np.array([[1000.0, 0, 800], [0, 1000, 450], [0, 0, 1]])
IDENTITY = [1.0, 0, 0, 0]


def test_occlusion_by_nearer_boxes_only():
    boxes = np.array([[0, 0, 10, 10], [5, 0, 15, 10], [100, 100, 110, 110]], dtype=float)
    occlusion = occlusion_fractions(boxes, np.array([10.0, 5.0, 1.0]))
    assert occlusion[0] == pytest.approx(0.5)  # right half covered by the nearer box 1
    assert occlusion[1] == 0.0 and occlusion[2] == 0.0


def test_camera_ground_truth_projects_clips_and_orders():
    # Two boxes straight ahead: a near one hides most of a far one behind it; a third is behind the camera.
    centers = np.array([[0, 0, 10.0], [0, 0, 30.0], [0, 0, -10.0]])
    sizes = np.array([[2.0, 4.0, 1.5]] * 3)
    rotations = np.array([IDENTITY] * 3)
    gt = camera_ground_truth(np.arange(3), np.array(["car", "car", "car"]), centers, sizes, rotations, K, (1600, 900))
    assert gt.annotation_rows.tolist() == [0, 1]
    assert gt.occlusion[0] == 0 and gt.occlusion[1] == 1.0
    assert gt.distance.tolist() == pytest.approx([10.0, 30.0])
    assert np.all(gt.truncation == 0) and gt.visibility[1] == 0
