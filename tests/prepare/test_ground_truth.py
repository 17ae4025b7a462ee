import numpy as np
import pytest

from sianms_cli.prepare.ground_truth import camera_ground_truth

K = np.array([[1000.0, 0, 800], [0, 1000, 450], [0, 0, 1]])
IDENTITY = [1.0, 0, 0, 0]


def test_camera_ground_truth_projects_clips_and_orders():
    # Two boxes straight ahead: a near one hides most of a far one behind it; a third is behind the camera.
    centers = np.array([[0, 0, 10.0], [0, 0, 30.0], [0, 0, -10.0]])
    sizes = np.array([[2.0, 4.0, 1.5]] * 3)
    rotations = np.array([IDENTITY] * 3)
    gt = camera_ground_truth(np.array(["car", "truck", "car"]), centers, sizes, rotations, K, (1600, 900))
    assert gt.ids.tolist() == [0, 1] and gt.classes.tolist() == ["car", "truck"]
    assert gt.occlusion[0] == 0 and gt.occlusion[1] == 1.0
    assert gt.distance.tolist() == pytest.approx([10.0, 30.0])
    assert np.all(gt.truncation == 0) and gt.visibility[1] == 0
    # The near car's length (4 m, along camera x) spans 4 m at the depth of its nearest face:
    # its height (1.5 m) lies along camera z with the identity rotation, so 10 - 0.75 m.
    assert gt.boxes[0, 2] - gt.boxes[0, 0] == pytest.approx(4.0 / 9.25 * 1000)


def test_a_box_cut_by_the_image_border_is_truncated():
    gt = camera_ground_truth(np.array(["car"]), np.array([[8.0, 0, 10]]), np.array([[2.0, 4.0, 1.5]]),
                             np.array([IDENTITY]), K, (1600, 900))
    assert 0 < gt.truncation[0] < 1 and gt.boxes[0, 2] == 1600
