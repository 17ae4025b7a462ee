import numpy as np
import pytest

from sianms_cli.detection2d.association import associate
from sianms_cli.detection2d.detections import GroundTruth2D
from sianms_cli.detection2d.simulated import (
    DEFAULT_CLASS_MODELS, SimulatedDetectorConfig, detection_probability, simulate_detections,
)
from sianms_cli.errors import SianmsError

SIZE = (1600, 900)


def ground_truth(count, height=80.0, occlusion=0.0, truncation=0.0, distance=20.0, cls="car"):
    """``count`` car boxes in a row, well apart so they never overlap."""
    x = 10 + (np.arange(count) % 10) * 150.0
    y = 300 + (np.arange(count) // 10 % 5) * 0.0
    width = 1.6 * height
    boxes = np.stack([x, y, x + min(width, 140), y + height], axis=1)
    full = lambda v: np.full(count, v, dtype=float)  # noqa: E731
    return GroundTruth2D(np.arange(count), boxes, np.full(count, cls), full(truncation), full(occlusion),
                         full(distance))


def recall(gt, images=40, seed=0, **kwargs):
    found = total = 0
    ious = []
    for i in range(images):
        det = simulate_detections(gt, SIZE, np.random.default_rng([seed, i]), **kwargs)
        match, iou = associate(det.boxes, gt.boxes, 0.3, det.classes, gt.classes)
        found += int((match >= 0).sum())
        total += len(gt)
        ious += iou[match >= 0].tolist()
    return found / total, np.array(ious)


def test_same_generator_same_detections():
    gt = ground_truth(10)
    a = simulate_detections(gt, SIZE, np.random.default_rng(4))
    b = simulate_detections(gt, SIZE, np.random.default_rng(4))
    assert np.array_equal(a.boxes, b.boxes) and np.array_equal(a.scores, b.scores)
    assert np.all(np.diff(a.scores) <= 0)


def test_misses_rise_with_occlusion_truncation_and_distance():
    base, _ = recall(ground_truth(10))
    assert base > 0.85
    assert recall(ground_truth(10, occlusion=0.6))[0] < base - 0.3
    assert recall(ground_truth(10, truncation=0.7))[0] < base - 0.3
    far = ground_truth(10, height=2200 / 70, distance=70.0)  # a car at 70 m
    assert recall(far)[0] < base - 0.2


def test_jitter_grows_with_truncation_and_distance():
    _, near = recall(ground_truth(10))
    _, truncated = recall(ground_truth(10, truncation=0.4), images=120)
    _, far = recall(ground_truth(10, distance=60.0), images=60)
    assert near.mean() > far.mean() > 0 and near.mean() > truncated.mean()


def test_scores_follow_visibility():
    config = SimulatedDetectorConfig(score_threshold=0.0)
    visible = [simulate_detections(ground_truth(10), SIZE, np.random.default_rng(i), config) for i in range(30)]
    hidden = [simulate_detections(ground_truth(10, occlusion=0.5), SIZE, np.random.default_rng(i), config)
              for i in range(30)]
    def tp_scores(runs, gt):
        out = []
        for det in runs:
            match, _ = associate(det.boxes, gt.boxes, 0.3, det.classes, gt.classes)
            out += det.scores[match >= 0].tolist()
        return np.mean(out)
    assert tp_scores(visible, ground_truth(10)) > tp_scores(hidden, ground_truth(10)) + 0.1


def test_false_positives_lie_on_the_background():
    gt = ground_truth(10)
    fps = 0
    for i in range(100):
        det = simulate_detections(gt, SIZE, np.random.default_rng(i))
        match, _ = associate(det.boxes, gt.boxes, 1e-9)
        unmatched = det.boxes[match < 0]
        fps += len(unmatched)
        from sianms_cli.detection2d.association import box_iou
        if len(unmatched):
            assert box_iou(unmatched, gt.boxes).max() <= 0.2 + 1e-9
    assert fps > 20  # about fp_per_image * classes per image


def test_per_class_parameters_and_unknown_class():
    assert DEFAULT_CLASS_MODELS["pedestrian"] != DEFAULT_CLASS_MODELS["car"]
    p_car = detection_probability(DEFAULT_CLASS_MODELS["car"], np.array([40.0]), 0, 0, np.array([20.0]))
    p_ped = detection_probability(DEFAULT_CLASS_MODELS["pedestrian"], np.array([40.0]), 0, 0, np.array([20.0]))
    assert p_car > p_ped
    with pytest.raises(SianmsError, match="no model for class 'barrier'"):
        SimulatedDetectorConfig(classes=("car", "barrier"))
    with pytest.raises(SianmsError, match="unknown detection class"):
        SimulatedDetectorConfig(classes=("cat",))
