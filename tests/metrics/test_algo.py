"""The metric core against the devkit's own unit tests and a slow port of the
devkit's ``accumulate`` (devkit_port.py), at threshold and tie edges."""

from __future__ import annotations

import itertools
import warnings
import random

import numpy as np
import pytest

from devkit_port import accumulate_reference
from sianms_cli.metrics.algo import (
    MetricData,
    accumulate,
    accumulate_thresholds,
    angle_diff,
    attr_acc,
    calc_ap,
    calc_tp,
    center_distance,
    cummean,
    fma,
    greedy_match,
    norm_2d,
    processing_order,
    scale_iou,
    velocity_l2,
    yaw_diff,
)
from sianms_cli.metrics.algo import _NORM_FORMULAS, _norm_probes, _norm_rounding
from sianms_cli.metrics.boxes import ATTRIBUTE, TP_METRICS, make_boxes
from sianms_cli.metrics.config import load_config
from sianms_cli.metrics.metrics import NAN_TP_METRICS, summarize, threshold_key
from sianms_cli.geometry.quaternion import yaw_to_quat

# --------------------------------------------------------------------------- devkit test_utils


def test_scale_iou_devkit_cases():
    assert scale_iou([4, 4, 4], [4, 4, 4]) == 1
    assert scale_iou([2, 2, 2], [1, 1, 1]) == 1 / 8
    assert scale_iou([1, 1, 1], [2, 2, 2]) == 1 / 8
    assert scale_iou([0.96, 0.37, 0.69], [0.32, 0.01, 0.39]) == pytest.approx(0.00509204, abs=1e-7)
    for gt, pred in (([0, 4, 4], [4, 4, 4]), ([0, 4, 4], [4, 0, 4]), ([4, 4, 4], [4, -5, 4])):
        with pytest.raises(ValueError):
            scale_iou(gt, pred)


def test_yaw_diff_devkit_cases():
    assert yaw_diff(np.pi / 8, np.pi / 8) == pytest.approx(0)
    for yaw_in in np.linspace(-10, 10, 100):
        expected = yaw_in % (2 * np.pi)
        if expected > np.pi:
            expected = 2 * np.pi - expected
        assert yaw_diff(0.0, yaw_in) == pytest.approx(expected)
    assert yaw_diff(1.1 * np.pi, 0.9 * np.pi) == pytest.approx(0.2 * np.pi)


@pytest.mark.parametrize(("a", "b", "period", "expected"), [
    (90, 0, 360, 90), (90, 0, 180, 90), (90, 0, 90, 0), (0, 90, 90, 0), (0, 180, 180, 0),
    (0, 180, 360, 180), (0, 180 + 360 * 200, 360, 180),
])
def test_angle_diff_devkit_cases(a, b, period, expected):
    assert abs(angle_diff(np.radians(a), np.radians(b), np.radians(period))) == pytest.approx(np.radians(expected))


def test_center_distance_and_velocity_devkit_cases():
    assert center_distance([4, 4, 5], [4, 4, 5]) == pytest.approx(0)
    assert center_distance([4, 4, 4], [3, 3, 3]) == pytest.approx(np.sqrt(2))  # z ignored
    assert center_distance([-1, -1, -1], [1, 1, 1]) == pytest.approx(np.sqrt(8))
    assert center_distance([4.2, 2.8, 4.2], [-1.45, 3.5, 3.9]) == pytest.approx(np.hypot(-1.45 - 4.2, 3.5 - 2.8))
    assert velocity_l2([4, 4], [4, 4]) == pytest.approx(0)
    assert velocity_l2([-1, -1], [1, 1]) == pytest.approx(np.sqrt(8))
    assert velocity_l2([8.2, 1.4], [6.4, -9.4]) == pytest.approx(np.hypot(6.4 - 8.2, -9.4 - 1.4))
    assert np.isnan(velocity_l2([np.nan, 0], [1, 1]))


@pytest.mark.parametrize(("values", "expected"), [
    ((np.nan, 5), (0, 5)),
    ((5, 2, np.nan), (5, 3.5, 3.5)),
    ((np.nan, 4.5, np.nan), (0, 4.5, 4.5)),
    ((np.nan, np.nan, np.nan, np.nan), (1, 1, 1, 1)),
    ((np.nan,), (1,)),
    ((4,), (4.0,)),
    ((np.nan, 3.58, 2.14, np.nan, 9, 1.48, np.nan), (0, 3.58, 2.86, 2.86, 4.906666, 4.05, 4.05)),
])
def test_cummean_devkit_cases(values, expected):
    np.testing.assert_array_almost_equal(cummean(np.array(values, dtype=float)), np.array(expected))


def test_attr_acc_devkit_cases():
    parked, moving = ATTRIBUTE["vehicle.parked"], ATTRIBUTE["vehicle.moving"]
    assert attr_acc(parked, parked) == 1.0
    assert attr_acc(parked, moving) == 0.0
    assert np.isnan(attr_acc(-1, parked))


# --------------------------------------------------------------------------- distances


def test_norm_2d_rounds_like_the_devkits_linalg_norm():
    # np.linalg.norm of a 2-vector is the devkit's distance; ours must agree to the bit.
    rng = np.random.default_rng(7)
    vectors = np.concatenate([rng.normal(0, 30, (3000, 2)), rng.normal(0, 1e-3, (500, 2)),
                              np.round(rng.uniform(-5, 5, (500, 2)), 1)])
    expected = np.array([np.linalg.norm(v) for v in vectors])
    assert np.array_equal(norm_2d(vectors[:, 0], vectors[:, 1]), expected)


def test_the_norm_probe_tells_every_known_blas_rounding_apart():
    # The three roundings OpenBLAS kernels give a 2-vector's norm; the probe must be able to pick any.
    probes = _norm_probes()
    lengths = {name: formula(probes[:, 0], probes[:, 1]) for name, formula in _NORM_FORMULAS.items()}
    for first, second in itertools.combinations(lengths, 2):
        assert np.sum(lengths[first] != lengths[second]) >= 10, (first, second)
    assert _norm_rounding() in _NORM_FORMULAS


def test_fma_is_correctly_rounded():
    from fractions import Fraction

    rng = np.random.default_rng(3)
    a, b, c = rng.normal(0, 40, (3, 4000))
    exact = [float(Fraction(x) * Fraction(y) + Fraction(z)) for x, y, z in zip(a, b, c)]
    assert np.array_equal(fma(a, b, c), exact)


# --------------------------------------------------------------------------- devkit test_algo


def _boxes(items: dict[str, list[dict]], score_default: float = -1.0):
    """A box table from the devkit tests' {sample: [box dict]} with their defaults."""
    samples = {name: i for i, name in enumerate(items)}
    rows = [(samples[s], box) for s, boxes in items.items() for box in boxes]
    defaults = {"trans": (0, 0, 0), "size": (1, 1, 1), "rot": (1, 0, 0, 0), "vel": (0, 0),
                "attr": "vehicle.parked", "score": score_default, "name": "car"}
    rows = [(s, {**defaults, **box}) for s, box in rows]
    if not rows:
        return make_boxes(np.zeros(0, int), 0, np.zeros((0, 3)))
    return make_boxes([s for s, _ in rows], [b["name"] for _, b in rows],
                      [b["trans"] for _, b in rows], [b["size"] for _, b in rows], [b["rot"] for _, b in rows],
                      [b["vel"] for _, b in rows], [b["score"] for _, b in rows], [b["attr"] for _, b in rows])


def _tables(gts, preds):
    # One sample index space for both sides, as the devkit keys both by sample token.
    names = list(dict.fromkeys([*gts, *preds]))
    return (_boxes({n: gts.get(n, []) for n in names}), _boxes({n: preds.get(n, []) for n in names}))


CAR1 = {"trans": (1, 1, 1), "name": "car", "score": 1.0}
CAR2 = {"trans": (3, 3, 1), "name": "car", "score": 0.7}
BICYCLE1 = {"trans": (5, 5, 1), "name": "bicycle", "score": 1.0}


@pytest.mark.parametrize(("gts", "preds", "target"), [
    ({"s1": []}, {"s1": [CAR1]}, 0.0),
    ({"s1": [CAR1]}, {"s1": []}, 0.0),
    ({"s1": []}, {"s1": []}, 0.0),
    ({"s1": [CAR1]}, {"s1": [CAR1]}, 1.0),
    ({"s1": [CAR1, CAR2]}, {"s1": [CAR1]}, 0.4 / 0.9),
    ({"s1": [CAR1]}, {"s1": [CAR1, CAR2]}, 1.0),
    ({"s1": [CAR2]}, {"s1": [CAR1, CAR2]}, ((0.8 * 0.4) / 2) / (0.9 * 0.9)),
    ({"s1": [CAR1]}, {"s1": [CAR1, BICYCLE1]}, 1.0),
    ({"s1": [CAR1], "s2": [CAR2]}, {"s1": [CAR1], "s2": [CAR2]}, 1.0),
    ({"s1": [CAR1], "s2": []}, {"s1": [CAR1], "s2": []}, 1.0),
    ({"s1": [CAR1], "s2": [CAR2]}, {"s1": [CAR1], "s2": []}, 0.4 / 0.9),
])
def test_ap_simple_devkit_cases(gts, preds, target):
    gt, pred = _tables(gts, preds)
    ap = calc_ap(accumulate(gt, pred, "car", 2.0), min_recall=0.1, min_precision=0.1)
    assert abs(ap - target) <= 0.01


GT1 = {"trans": (1, 1, 1)}
GT2 = {"trans": (10, 10, 1), "size": (2, 2, 2)}
GT3 = {"trans": (20, 20, 1), "size": (2, 4, 2)}
PRED1 = {"trans": (1, 1, 1), "score": 1.0}
PRED2 = {"trans": (11, 10, 1), "size": (2, 2, 2), "score": 0.9}
PRED3 = {"trans": (100, 10, 1), "size": (2, 2, 2), "score": 0.8}
PRED4 = {"trans": (20, 20, 1), "size": (2, 4, 2), "score": 0.7}
PRED5 = {"trans": (21, 20, 1), "size": (2, 4, 2), "score": 0.7}
TWO = ((0 + 0) / 2 + (0 + 0.5) / 2) / (2 * 0.9)
THREE = ((0 + 0) / 2 + (0 + 0.5) / 2 + (0.5 + 0.33) / 2) / (3 * 0.9)


@pytest.mark.parametrize(("gts", "preds", "target"), [
    ({"s1": [GT2]}, {"s1": [PRED2]}, 1.0),
    ({"s1": [GT1, GT2]}, {"s1": [PRED1, PRED2]}, TWO),
    ({"s1": [GT1, GT2]}, {"s1": [PRED1, PRED2, PRED3]}, TWO),
    ({"s1": [GT1, GT2, GT3]}, {"s1": [PRED1, PRED2, PRED4]}, THREE),
    ({"s1": [GT2, GT3]}, {"s1": [PRED2, PRED5]}, 1.0),
    ({"s1": [GT1], "s2": [GT2]}, {"s1": [PRED1], "s2": [PRED2]}, TWO),
    ({"s1": [GT1], "s2": [GT2], "s3": []}, {"s1": [PRED1], "s2": [PRED2, PRED3], "s3": []}, TWO),
    ({"s1": [GT2, GT3], "s2": [GT3]}, {"s1": [PRED2], "s2": [PRED4 | {"trans": (21, 20, 1)}]}, 1.0),
])
def test_tp_simple_devkit_cases(gts, preds, target):
    gt, pred = _tables(gts, preds)
    assert abs(calc_tp(accumulate(gt, pred, "car", 2.0), 0.1, "trans_err") - target) <= 0.01


@pytest.mark.parametrize("metric", TP_METRICS)
def test_tp_errors_without_matches_or_when_perfect(metric):
    car1, car2 = {"trans": (1, 1, 1), "score": 1.0}, {"trans": (3, 3, 1), "score": 1.0}
    bike = {"trans": (1, 1, 1), "score": 1.0, "name": "bicycle", "attr": "cycle.with_rider"}
    for preds in ([car2], [bike]):
        gt, pred = _tables({"s1": [car1]}, {"s1": preds})
        assert calc_tp(accumulate(gt, pred, "car", 2.0), 0.1, metric) == 1.0
    for score in (1.0, 0.3):
        gt, pred = _tables({"s1": [car1]}, {"s1": [car1 | {"score": score}]})
        assert calc_tp(accumulate(gt, pred, "car", 2.0), 0.1, metric) == pytest.approx(0.0, abs=1e-12)


def test_calc_ap_and_calc_tp_argument_checks():
    rng = np.random.RandomState(42)
    md = MetricData(np.linspace(0, 1, 101), rng.random_sample(101), np.linspace(0, 1, 101)[::-1],
                    *(rng.random_sample(101) for _ in TP_METRICS))
    assert calc_tp(md, min_recall=1, metric_name="trans_err") == 1.0
    for min_recall, min_precision in ((-0.5, 0.4), (0.5, -0.8), (0.7, 1), (1.2, 0)):
        with pytest.raises(ValueError):
            calc_ap(md, min_recall, min_precision)


def _mock_results(py: random.Random, legacy: np.random.RandomState, name: str):
    """The devkit's TestAlgo._mock_results(30, 3, 25, name), draw for draw."""
    rel = {"pedestrian": ["pedestrian.moving", "pedestrian.sitting_lying_down", "pedestrian.standing"],
           "bicycle": ["cycle.with_rider", "cycle.without_rider"],
           "motorcycle": ["cycle.with_rider", "cycle.without_rider"],
           "traffic_cone": [], "barrier": []}.get(name, ["vehicle.moving", "vehicle.parked", "vehicle.stopped"])

    def boxes(per_sample: int, scale: float):
        rows = []
        for sample in range(30):
            for _ in range(per_sample):
                xy = legacy.rand(2) * scale
                size, rotation, velocity = legacy.rand(3) * 4, legacy.rand(4), legacy.rand(3)[:2] * 4
                score = py.random()
                attribute = rel[legacy.randint(0, len(rel))] if rel else ""
                py.random()  # ego_translation, unused by accumulate
                rows.append((sample, (xy[0], xy[1], 0.0), size, rotation, velocity, score, attribute))
        return make_boxes(*(list(column) for column in zip(*[(r[0], name) + r[1:] for r in rows])))

    return boxes(3, 15), boxes(25, 10)


def test_nd_score_of_the_devkits_random_mock():
    # random.seed(42) and np.random.seed(42), then 10 classes x (30 samples x 3 GT, 25 predictions),
    # accumulated at 2 m for every threshold: the devkit asserts NDS == 0.08606662159639042.
    py, legacy = random.Random(42), np.random.RandomState(42)
    config = load_config("detection_cvpr_2019")
    label_aps, label_tp = {}, {}
    for name in config.class_names:
        gt, pred = _mock_results(py, legacy, name)
        md = accumulate(gt, pred, name, 2.0)
        label_aps[name] = {threshold_key(th): calc_ap(md, 0.1, 0.1) for th in config.dist_ths}
        label_tp[name] = {m: np.nan if m in NAN_TP_METRICS.get(name, ()) else calc_tp(md, 0.1, m) for m in TP_METRICS}
    nds = summarize(label_aps, label_tp, config)["nd_score"]
    # Same mock, same matches; the last bit can differ through arctan2/quaternion rounding.
    assert nds == pytest.approx(0.08606662159639042, abs=1e-15)


# --------------------------------------------------------------------------- matching semantics


def test_processing_order_puts_the_later_row_first_on_equal_scores():
    scores = np.array([0.5, 0.9, 0.5, 0.9, 0.1, 0.5])
    assert processing_order(scores).tolist() == [3, 1, 5, 2, 0, 4]
    expected = [i for (v, i) in sorted((v, i) for (i, v) in enumerate(scores.tolist()))][::-1]
    assert processing_order(scores).tolist() == expected


def test_exactly_at_the_threshold_is_a_miss():
    gt = make_boxes(0, "car", [[0.0, 0.0, 0.0]])
    for offset, matched in ((2.0, False), (np.nextafter(2.0, 0), True)):
        pred = make_boxes(0, "car", [[offset, 0.0, 0.0]], score=0.9)
        md = accumulate(gt, pred, "car", 2.0)
        assert (md.max_recall_ind > 0) == matched


def test_first_gt_in_list_order_wins_a_distance_tie():
    gt = make_boxes(0, "car", [[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]], size=[(1, 1, 1), (2, 2, 2)])
    pred = make_boxes(0, "car", [[0.0, 0.0, 0.0]], size=(1, 1, 1), score=0.9)
    (matched,), _ = greedy_match(gt["sample"], gt["translation"], pred["sample"], pred["translation"],
                                 processing_order(pred["score"]), [2.0])
    assert matched.tolist() == [0]
    # The TP errors come from the first GT (same size): no scale error.
    assert calc_tp(accumulate(gt, pred, "car", 2.0), 0.1, "scale_err") == pytest.approx(0.0)


def test_a_duplicate_is_a_false_positive_unless_another_gt_is_free():
    gt = make_boxes(0, "car", [[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    pred = make_boxes(0, "car", [[0.1, 0.0, 0.0], [0.2, 0.0, 0.0]], score=[0.9, 0.8])
    (at_2m, at_4m), _ = greedy_match(gt["sample"], gt["translation"], pred["sample"], pred["translation"],
                                     processing_order(pred["score"]), [2.0, 4.0])
    assert at_2m.tolist() == [0, -1]
    assert at_4m.tolist() == [0, 1]


def _random_tables(rng: np.random.Generator, classes=("car", "barrier", "bicycle")):
    samples = int(rng.integers(1, 6))
    grid = float(rng.choice([0.25, 0.5, 1.0]))  # grid positions put many pairs exactly on a threshold

    def table(count: int, is_gt: bool):
        xy = np.round(rng.uniform(0, 6, (count, 2)) / grid) * grid
        if not is_gt:
            xy += rng.choice([0.0, 0.0, 0.1], (count, 2))
        yaw = rng.uniform(-3, 3, count)
        velocity = rng.normal(size=(count, 2))
        if is_gt:
            velocity[rng.random(count) < 0.1] = np.nan
        return make_boxes(rng.integers(0, samples, count), rng.choice(classes, count), np.c_[xy, np.zeros(count)],
                          size=rng.uniform(0.5, 3, (count, 3)), rotation=yaw_to_quat(yaw), velocity=velocity,
                          score=rng.choice([0.1, 0.5, 0.9, 1.0], count) if not is_gt else -1.0,
                          attribute=rng.integers(-1, 8, count))

    return table(int(rng.integers(0, 25)), True), table(int(rng.integers(0, 40)), False)


@pytest.mark.parametrize("seed", range(4))
def test_vectorised_matching_equals_the_devkit_port_to_the_bit(seed):
    rng = np.random.default_rng(seed)
    for _ in range(40):
        gt, pred = _random_tables(rng)
        for name in ("car", "barrier"):
            ours = accumulate_thresholds(gt, pred, name, [0.5, 1.0, 2.0, 4.0])
            for threshold, md in zip([0.5, 1.0, 2.0, 4.0], ours):
                assert md == accumulate_reference(gt, pred, name, threshold)


def test_crowded_sample_needs_many_rounds_and_still_matches():
    # 300 predictions of one class on 200 GT in one sample: 300 sequential decisions.
    rng = np.random.default_rng(11)
    gt = make_boxes(0, "car", np.c_[rng.uniform(0, 10, (200, 2)), np.zeros(200)])
    pred = make_boxes(0, "car", np.c_[rng.uniform(0, 10, (300, 2)), np.zeros(300)],
                      score=np.round(rng.random(300), 1))
    for threshold, md in zip([0.5, 2.0], accumulate_thresholds(gt, pred, "car", [0.5, 2.0])):
        assert md == accumulate_reference(gt, pred, "car", threshold)


def test_absurd_predictions_score_as_in_the_devkit_without_numpy_warnings():
    # A detector bug writes a 1e200 m box or a 1e308 m/s velocity: the devkit's arithmetic gives
    # IoU 0 and an infinite velocity error (with numpy's overflow warnings); ours, the same, silently.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert scale_iou(np.array([[2.0, 4.5, 1.5]]), np.array([[1e200, 1e200, 1e200]])).tolist() == [0.0]
        assert velocity_l2(np.array([[0.0, 0.0]]), np.array([[1e308, -1e308]])).tolist() == [np.inf]
