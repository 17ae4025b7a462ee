"""The nuScenes detection metric on box tables: greedy matching, accumulation, AP and TP errors.

Free functions over arrays, reproducing nuscenes-devkit 1.2.0 (``eval/detection/algo.py`` and
``eval/common/utils.py``) number for number, without a Python object per box
(docs/metrics.md#definitions):

- :func:`accumulate` / :func:`accumulate_thresholds` give the devkit's 101-point
  :class:`MetricData` of one class at one or several matching thresholds;
- :func:`calc_ap` and :func:`calc_tp` integrate them as the devkit does;
- the element-wise helpers (:func:`center_distance`, :func:`scale_iou`, :func:`yaw_diff`, ...)
  broadcast over arrays of boxes.

Matching is the devkit's: predictions in descending score, the row *later* in the table first
on equal scores; each takes the nearest still-unmatched ground-truth box of its class in its
sample (the first in list order on a distance tie) and is a true positive iff that distance is
``< dist_th``. Only candidate pairs (same sample, distance below the largest threshold) are
built, all at once, sorted by (processing rank, distance, ground-truth order); the greedy
assignment then runs in rounds, round k resolving every sample's k-th prediction with a
candidate, so within a sample the devkit's order holds and the loop count is the largest
number of such predictions in one sample.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from sianms_cli.metrics.boxes import LABEL, NO_ATTRIBUTE, TP_METRICS
from sianms_cli.geometry.quaternion import quat_yaw

NELEM = 101
"""Number of recall points of the interpolated curves (0 %, 1 %, ..., 100 %)."""

_SPLITTER = 134217729.0  # 2**27 + 1: Veltkamp split of a float64 into two 26-bit halves
_CHUNK_PAIRS = 1 << 22  # candidate pairs enumerated at once (about 100 MB of temporaries)


# --------------------------------------------------------------------------- element-wise


def fma(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """``a * b + c`` rounded once, as a fused multiply-add, element-wise in float64.

    numpy has no FMA, yet the devkit's distances go through a BLAS kernel that, on some
    CPUs, fuses (see :func:`norm_2d`). Emulated with Dekker's error-free product and
    Knuth's two-sum: ``a*b = p + e`` and ``c + p = s + t`` exactly, result ``s + (t + e)``.
    That is the correctly rounded value except in double-rounding cases of probability
    about 2**-50. Operands beyond 1e150 in magnitude (no such coordinate is evaluated) fall
    back to ``a * b + c``.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    c = np.asarray(c, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        product = a * b
        a_split = _SPLITTER * a
        a_high = a_split - (a_split - a)
        a_low = a - a_high
        b_split = _SPLITTER * b
        b_high = b_split - (b_split - b)
        b_low = b - b_high
        product_error = ((a_high * b_high - product) + a_high * b_low + a_low * b_high) + a_low * b_low
        total = c + product
        virtual = total - c
        sum_error = (c - (total - virtual)) + (product - virtual)
        fused = total + (sum_error + product_error)
        safe = (np.abs(a) < 1e150) & (np.abs(b) < 1e150)
    return np.where(safe, fused, product + c)


def norm_2d(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Length of 2-D vectors (x, y), rounded as the devkit's ``np.linalg.norm`` of a 2-vector.

    ``np.linalg.norm`` of a 1-D float64 array calls BLAS ``ddot``, and OpenBLAS picks its kernel
    by CPU: on AVX-512 machines it accumulates ``fma(y, y, x*x)``, on AVX2 ones it rounds as
    ``sqrt(x*x + y*y)``; the two differ in the last bit for about 7 % of vectors, which decides
    distance ties and threshold edges. :func:`_norm_rounding` finds which this machine's BLAS
    does, once; the fused step is emulated by :func:`fma`.
    """
    with np.errstate(over="ignore"):  # a velocity of 1e200 m/s: inf, as the devkit's norm gives
        return _NORM_FORMULAS[_norm_rounding()](np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))


_NORM_FORMULAS = {
    "fma(y, y, x*x)": lambda x, y: np.sqrt(fma(y, y, x * x)),
    "x*x + y*y": lambda x, y: np.sqrt(x * x + y * y),
    "fma(x, x, y*y)": lambda x, y: np.sqrt(fma(x, x, y * y)),
}


@functools.cache
def _norm_rounding() -> str:
    """The :data:`_NORM_FORMULAS` key that reproduces ``np.linalg.norm`` of 2-vectors here.

    Probed on 512 seeded vectors, of which 34 to 52 tell each two formulas apart; a BLAS that
    rounds like none of them gets the one that agrees most often.
    """
    probes = _norm_probes()
    blas = np.array([np.linalg.norm(vector) for vector in probes])
    agreement = {name: int(np.sum(formula(probes[:, 0], probes[:, 1]) == blas))
                 for name, formula in _NORM_FORMULAS.items()}
    return max(agreement, key=agreement.__getitem__)


def _norm_probes() -> np.ndarray:
    return np.random.default_rng(0).normal(0.0, 30.0, (512, 2))


def center_distance(gt_translation: np.ndarray, pred_translation: np.ndarray) -> np.ndarray:
    """BEV distance of box centres (x, y only; z ignored), metres.

    Args:
        gt_translation, pred_translation: (..., 2+) centres, broadcast against each other.
    """
    gt = np.asarray(gt_translation, dtype=np.float64)
    pred = np.asarray(pred_translation, dtype=np.float64)
    return norm_2d(pred[..., 0] - gt[..., 0], pred[..., 1] - gt[..., 1])


def velocity_l2(gt_velocity: np.ndarray, pred_velocity: np.ndarray) -> np.ndarray:
    """L2 norm of the (vx, vy) difference, m/s; NaN where either velocity is NaN."""
    gt = np.asarray(gt_velocity, dtype=np.float64)
    pred = np.asarray(pred_velocity, dtype=np.float64)
    return norm_2d(pred[..., 0] - gt[..., 0], pred[..., 1] - gt[..., 1])


def scale_iou(gt_size: np.ndarray, pred_size: np.ndarray) -> np.ndarray:
    """3-D IoU of boxes aligned on centre and orientation: prod(min) / (V_gt + V_pred - prod(min)).

    Args:
        gt_size, pred_size: (..., 3) sizes (w, l, h), metres, all > 0.

    Raises:
        ValueError: a size is not positive (the devkit asserts).
    """
    gt = np.asarray(gt_size, dtype=np.float64)
    pred = np.asarray(pred_size, dtype=np.float64)
    if not (np.all(gt > 0) and np.all(pred > 0)):
        raise ValueError("box sizes must be > 0 in every dimension")
    smallest = np.minimum(gt, pred)
    intersection = smallest[..., 0] * smallest[..., 1] * smallest[..., 2]
    volume_gt = gt[..., 0] * gt[..., 1] * gt[..., 2]
    with np.errstate(over="ignore"):  # a predicted 1e200 m box: volume inf, IoU 0, as in the devkit
        volume_pred = pred[..., 0] * pred[..., 1] * pred[..., 2]
    return intersection / (volume_gt + volume_pred - intersection)


def angle_diff(x: np.ndarray, y: np.ndarray, period: float) -> np.ndarray:
    """Signed smallest difference x - y of angles with the given period, radians, in (-pi, pi]."""
    diff = np.remainder(np.asarray(x, dtype=np.float64) - y + period / 2, period) - period / 2
    return np.where(diff > np.pi, diff - 2 * np.pi, diff)


def yaw_diff(gt_yaw: np.ndarray, pred_yaw: np.ndarray, period: float = 2 * np.pi) -> np.ndarray:
    """Absolute yaw difference in [0, pi] (period 2 pi) or [0, pi/2] (period pi, barriers)."""
    return np.abs(angle_diff(gt_yaw, pred_yaw, period))


def attr_acc(gt_attribute: np.ndarray, pred_attribute: np.ndarray) -> np.ndarray:
    """1.0 where the attribute indices agree, 0.0 where not, NaN where the GT has none (-1)."""
    gt = np.asarray(gt_attribute)
    equal = (gt == np.asarray(pred_attribute)).astype(np.float64)
    return np.where(gt == NO_ATTRIBUTE, np.nan, equal)


def cummean(x: np.ndarray) -> np.ndarray:
    """Cumulative mean that skips NaNs: 0 before the first number; all NaN gives ones."""
    x = np.asarray(x, dtype=np.float64)
    if np.isnan(x).sum() == len(x):
        return np.ones(len(x))
    sums = np.nancumsum(x)
    counts = np.cumsum(~np.isnan(x))
    return np.divide(sums, counts, out=np.zeros_like(sums), where=counts != 0)


# --------------------------------------------------------------------------- metric data


@dataclass(frozen=True, eq=False)
class MetricData:
    """The devkit's ``DetectionMetricData``: 101-point curves of one class at one threshold.

    ``recall`` is linspace(0, 1, 101); ``precision`` and ``confidence`` (descending) are
    interpolated at those recalls; each TP error is its cumulative mean over true positives,
    interpolated at those confidences.
    """

    recall: np.ndarray
    precision: np.ndarray
    confidence: np.ndarray
    trans_err: np.ndarray
    vel_err: np.ndarray
    scale_err: np.ndarray
    orient_err: np.ndarray
    attr_err: np.ndarray

    @property
    def max_recall_ind(self) -> int:
        """Index of the last non-zero confidence (the maximal recall reached), 0 if none."""
        nonzero = np.flatnonzero(self.confidence)
        return int(nonzero[-1]) if len(nonzero) else 0

    @property
    def max_recall(self) -> float:
        return float(self.recall[self.max_recall_ind])

    @classmethod
    def no_predictions(cls) -> MetricData:
        """Precision and confidence 0, every TP error 1: a class without a match or without GT."""
        return cls(np.linspace(0, 1, NELEM), np.zeros(NELEM), np.zeros(NELEM),
                   *(np.ones(NELEM) for _ in TP_METRICS))

    def serialize(self) -> dict[str, list[float]]:
        """The devkit's ``metrics_details.json`` entry (NaN kept as float)."""
        return {name: getattr(self, name).tolist() for name in _CURVES}

    @classmethod
    def deserialize(cls, content: dict) -> MetricData:
        return cls(**{name: np.asarray(content[name], dtype=np.float64) for name in _CURVES})

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, MetricData):
            return NotImplemented
        return all(np.array_equal(getattr(self, n), getattr(other, n), equal_nan=True) for n in _CURVES)


_CURVES = ("recall", "precision", "confidence", "trans_err", "vel_err", "scale_err", "orient_err", "attr_err")


# --------------------------------------------------------------------------- matching


def processing_order(scores: np.ndarray) -> np.ndarray:
    """The devkit's order of predictions: descending score, the later row first on ties.

    (The devkit sorts (score, index) pairs ascending and reverses the list.)
    """
    scores = np.asarray(scores, dtype=np.float64)
    count = len(scores)
    return (count - 1) - np.argsort(-scores[::-1], kind="stable")


def greedy_match(
    gt_sample: np.ndarray,
    gt_xy: np.ndarray,
    pred_sample: np.ndarray,
    pred_xy: np.ndarray,
    order: np.ndarray,
    dist_ths: Sequence[float],
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Greedy matching of one class's predictions to its ground truth, at several thresholds.

    Args:
        gt_sample, gt_xy: (G,) sample index and (G, 2+) centres of the GT boxes, in list order.
        pred_sample, pred_xy: (P,) and (P, 2+) of the predictions.
        order: (P,) processing order of the predictions (:func:`processing_order`).
        dist_ths: matching thresholds, metres.

    Returns:
        ``(matched, distance)``: per threshold, (P,) int64 the GT row each prediction took
        (-1 for a false positive) and (P,) float64 the distance to it (NaN for -1).
    """
    gt_sample = np.asarray(gt_sample, dtype=np.int64)
    pred_sample = np.asarray(pred_sample, dtype=np.int64)
    count = len(pred_sample)
    rank = np.empty(count, dtype=np.int64)
    rank[order] = np.arange(count)
    pair_pred, pair_gt, pair_dist = _candidate_pairs(gt_sample, gt_xy, pred_sample, pred_xy,
                                                     max(dist_ths, default=0.0))
    # Candidates of a prediction: nearest first, then GT list order (the devkit's strict <).
    sort = np.lexsort((pair_gt, pair_dist, rank[pair_pred]))
    pair_pred, pair_gt, pair_dist = pair_pred[sort], pair_gt[sort], pair_dist[sort]
    matched, distance = [], []
    for threshold in dist_ths:
        within = pair_dist < threshold
        taken = _greedy_rounds(pair_pred[within], pair_gt[within], pred_sample, len(gt_sample))
        chosen = np.full(count, -1, dtype=np.int64)
        chosen_dist = np.full(count, np.nan)
        kept = np.flatnonzero(within)[taken]
        chosen[pair_pred[kept]] = pair_gt[kept]
        chosen_dist[pair_pred[kept]] = pair_dist[kept]
        matched.append(chosen)
        distance.append(chosen_dist)
    return matched, distance


def _candidate_pairs(gt_sample, gt_xy, pred_sample, pred_xy, max_dist):
    """(pred row, GT row, distance) of every same-sample pair closer than ``max_dist``.

    Pairs are enumerated in chunks of predictions (a few million pairs each) so memory stays
    bounded however crowded a sample is. A cheap ``x*x + y*y`` test with a relative margin
    discards far pairs first; the devkit-exact distance (:func:`norm_2d`) is computed only
    for the rest.
    """
    gt_by_sample = np.argsort(gt_sample, kind="stable")
    sorted_samples = gt_sample[gt_by_sample]
    first = np.searchsorted(sorted_samples, pred_sample, side="left")
    counts = np.searchsorted(sorted_samples, pred_sample, side="right") - first
    gt_x, gt_y = (np.ascontiguousarray(gt_xy[:, k], dtype=np.float64) for k in (0, 1))
    pred_x, pred_y = (np.ascontiguousarray(pred_xy[:, k], dtype=np.float64) for k in (0, 1))
    coarse_limit = max_dist * max_dist * (1 + 1e-9)
    preds, gts, dists = [], [], []
    cumulative = np.cumsum(counts)
    start = 0
    while start < len(pred_sample):
        before = int(cumulative[start - 1]) if start else 0
        stop = max(int(np.searchsorted(cumulative, before + _CHUNK_PAIRS, side="right")), start + 1)
        chunk_counts = counts[start:stop]
        total = int(cumulative[stop - 1]) - before
        pred_rows = np.repeat(np.arange(start, stop), chunk_counts)
        # GT position of pair j of prediction i: first[i] + (j - pairs before i).
        positions = np.repeat(first[start:stop] - (cumulative[start:stop] - chunk_counts - before),
                              chunk_counts) + np.arange(total)
        gt_rows = gt_by_sample[positions]
        dx = pred_x[pred_rows] - gt_x[gt_rows]
        dy = pred_y[pred_rows] - gt_y[gt_rows]
        near = np.flatnonzero(dx * dx + dy * dy <= coarse_limit)
        dist = norm_2d(dx[near], dy[near])
        close = dist < max_dist
        preds.append(pred_rows[near[close]])
        gts.append(gt_rows[near[close]])
        dists.append(dist[close])
        start = stop
    if not preds:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    return np.concatenate(preds), np.concatenate(gts), np.concatenate(dists)


def _greedy_rounds(cand_pred: np.ndarray, cand_gt: np.ndarray, pred_sample: np.ndarray,
                   gt_count: int) -> np.ndarray:
    """Indices into the candidate list of the pairs the greedy assignment keeps.

    The candidates are sorted by (processing rank of the prediction, distance, GT row).
    """
    if len(cand_pred) == 0:
        return np.zeros(0, dtype=np.int64)
    starts = np.flatnonzero(np.r_[True, cand_pred[1:] != cand_pred[:-1]])
    lengths = np.diff(np.r_[starts, len(cand_pred)])
    samples = pred_sample[cand_pred[starts]]
    # Round of a prediction: how many predictions with candidates precede it in its sample.
    by_sample = np.argsort(samples, kind="stable")
    grouped = samples[by_sample]
    group_start = np.flatnonzero(np.r_[True, grouped[1:] != grouped[:-1]])
    group_sizes = np.diff(np.r_[group_start, len(grouped)])
    rounds = np.empty(len(samples), dtype=np.int64)
    rounds[by_sample] = np.arange(len(grouped)) - np.repeat(group_start, group_sizes)
    by_round = np.argsort(rounds, kind="stable")
    round_bounds = np.r_[0, np.cumsum(np.bincount(rounds))]

    taken = np.zeros(gt_count, dtype=bool)
    kept = []
    for k in range(len(round_bounds) - 1):
        active = by_round[round_bounds[k]:round_bounds[k + 1]]
        active_starts = starts[active]
        active_lengths = lengths[active]
        if np.all(active_lengths == 1):
            positions = active_starts
            free = ~taken[cand_gt[positions]]
            chosen = positions[free]
        else:
            segment = np.cumsum(active_lengths) - active_lengths
            local = np.arange(int(active_lengths.sum()))
            positions = np.repeat(active_starts - segment, active_lengths) + local
            free = ~taken[cand_gt[positions]]
            first_free = np.minimum.reduceat(np.where(free, local, len(local)), segment)
            chosen = positions[first_free[first_free < len(local)]]
        taken[cand_gt[chosen]] = True
        kept.append(chosen)
    return np.concatenate(kept)


# --------------------------------------------------------------------------- accumulation


def _label(class_name: str | int) -> int:
    return LABEL[class_name] if isinstance(class_name, str) else int(class_name)


class _Columns:
    """Contiguous per-field copies of the rows of one class, taken once for all thresholds."""

    def __init__(self, boxes: np.ndarray) -> None:
        self.sample = boxes["sample"].astype(np.int64)
        self.xy = np.ascontiguousarray(boxes["translation"][:, :2])
        self.velocity = np.ascontiguousarray(boxes["velocity"])
        self.size = np.ascontiguousarray(boxes["size"])
        self.rotation = np.ascontiguousarray(boxes["rotation"])
        self.attribute = boxes["attribute"].copy()
        self.score = boxes["score"].copy()
        self._yaw: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.sample)

    @property
    def yaw(self) -> np.ndarray:
        if self._yaw is None:
            self._yaw = quat_yaw(self.rotation) if len(self.rotation) else np.zeros(0)
        return self._yaw


def accumulate_thresholds(gt: np.ndarray, pred: np.ndarray, class_name: str | int,
                          dist_ths: Sequence[float]) -> list[MetricData]:
    """The devkit's ``accumulate`` at each threshold of ``dist_ths``, matching once per threshold.

    Args:
        gt, pred: box tables (:data:`~sianms_cli.metrics.boxes.BOX_DTYPE`), already
            filtered, rows in the devkit's order; only rows of ``class_name`` are used.
        class_name: detection class name or index.
        dist_ths: matching thresholds, metres.

    Returns:
        One :class:`MetricData` per threshold, in the order given.
    """
    label = _label(class_name)
    gt, pred = _of_label(gt, label), _of_label(pred, label)
    if len(gt) == 0:
        return [MetricData.no_predictions() for _ in dist_ths]
    gt_columns, pred_columns = _Columns(gt), _Columns(pred)
    order = processing_order(pred_columns.score)
    matched, distance = greedy_match(gt_columns.sample, gt_columns.xy, pred_columns.sample, pred_columns.xy, order,
                                     dist_ths)
    period = np.pi if label == LABEL["barrier"] else 2 * np.pi
    return [_metric_data(gt_columns, pred_columns, order, m, d, period) for m, d in zip(matched, distance)]


def accumulate(gt: np.ndarray, pred: np.ndarray, class_name: str | int, dist_th: float) -> MetricData:
    """The devkit's ``accumulate(gt, pred, class_name, center_distance, dist_th)``."""
    return accumulate_thresholds(gt, pred, class_name, [dist_th])[0]


def _of_label(boxes: np.ndarray, label: int) -> np.ndarray:
    """The rows of one class (no copy when every row is of that class)."""
    mine = boxes["label"] == label
    return boxes if mine.all() else boxes[mine]


def _metric_data(gt: _Columns, pred: _Columns, order, matched, distance, period) -> MetricData:
    is_tp = matched[order] >= 0
    if not is_tp.any():
        return MetricData.no_predictions()
    tp = np.cumsum(is_tp.astype(np.int64)).astype(float)
    fp = np.cumsum((~is_tp).astype(np.int64)).astype(float)
    conf = pred.score[order]
    precision = tp / (fp + tp)
    recall = tp / float(len(gt))
    recall_interp = np.linspace(0, 1, NELEM)
    precision = np.interp(recall_interp, recall, precision, right=0)
    conf = np.interp(recall_interp, recall, conf, right=0)

    p = order[is_tp]  # true positives in processing order
    g = matched[p]
    errors = {
        "trans_err": distance[p],
        "vel_err": velocity_l2(gt.velocity[g], pred.velocity[p]),
        "scale_err": 1 - scale_iou(gt.size[g], pred.size[p]),
        "orient_err": yaw_diff(gt.yaw[g], pred.yaw[p], period),
        "attr_err": 1 - attr_acc(gt.attribute[g], pred.attribute[p]),
    }
    match_conf = pred.score[p]
    curves = {
        name: np.interp(conf[::-1], match_conf[::-1], cummean(values)[::-1])[::-1]
        for name, values in errors.items()
    }
    return MetricData(recall=recall_interp, precision=precision, confidence=conf, **curves)


# --------------------------------------------------------------------------- integration


def calc_ap(md: MetricData, min_recall: float, min_precision: float) -> float:
    """Area under the precision curve above ``min_recall`` and ``min_precision``, normalised.

    Uses the bins from round(100 min_recall) + 1 to 100 (the min-recall bin excluded):
    mean(max(p - min_precision, 0)) / (1 - min_precision).
    """
    if not 0 <= min_precision < 1:
        raise ValueError(f"min_precision must be in [0, 1), got {min_precision}")
    if not 0 <= min_recall <= 1:
        raise ValueError(f"min_recall must be in [0, 1], got {min_recall}")
    precision = np.copy(md.precision)[round(100 * min_recall) + 1:]
    precision -= min_precision
    precision[precision < 0] = 0
    return float(np.mean(precision)) / (1.0 - min_precision)


def calc_tp(md: MetricData, min_recall: float, metric_name: str) -> float:
    """Mean of a TP-error curve from just above ``min_recall`` to the maximal recall reached;
    1.0 when that recall does not exceed ``min_recall``."""
    first = round(100 * min_recall) + 1
    last = md.max_recall_ind
    if last < first:
        return 1.0
    return float(np.mean(getattr(md, metric_name)[first:last + 1]))
