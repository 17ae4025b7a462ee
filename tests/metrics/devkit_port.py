"""A slow, line-by-line port of the devkit's ``accumulate`` (nuscenes-devkit 1.2.0,
``eval/detection/algo.py``) over box tables: one Python loop per prediction and per GT box,
distances by ``np.linalg.norm`` as the devkit computes them. The obviously-correct reference
our vectorised matching is compared with; tests only.
"""

from __future__ import annotations

import numpy as np

from sianms_cli.metrics.algo import NELEM, MetricData, cummean
from sianms_cli.metrics.boxes import LABEL, NO_ATTRIBUTE
from sianms_cli.geometry.quaternion import quat_yaw


def _angle_diff(x: float, y: float, period: float) -> float:
    diff = (x - y + period / 2) % period - period / 2
    if diff > np.pi:
        diff = diff - (2 * np.pi)
    return diff


def accumulate_reference(gt: np.ndarray, pred: np.ndarray, class_name: str, dist_th: float) -> MetricData:
    label = LABEL[class_name]
    npos = int(np.sum(gt["label"] == label))
    if npos == 0:
        return MetricData.no_predictions()
    gt_by_sample: dict[int, list[int]] = {}
    for row, sample in enumerate(gt["sample"].tolist()):
        gt_by_sample.setdefault(sample, []).append(row)
    pred_rows = [row for row in range(len(pred)) if pred["label"][row] == label]
    confs = [float(pred["score"][row]) for row in pred_rows]
    sortind = [i for (v, i) in sorted((v, i) for (i, v) in enumerate(confs))][::-1]
    tp, fp, conf = [], [], []
    match = {"trans_err": [], "vel_err": [], "scale_err": [], "orient_err": [], "attr_err": [], "conf": []}
    taken = set()
    for ind in sortind:
        p = pred[pred_rows[ind]]
        sample = int(p["sample"])
        min_dist, match_gt = np.inf, None
        for gt_idx, row in enumerate(gt_by_sample.get(sample, [])):
            g = gt[row]
            if g["label"] == label and (sample, gt_idx) not in taken:
                distance = np.linalg.norm(np.array(p["translation"][:2]) - np.array(g["translation"][:2]))
                if distance < min_dist:
                    min_dist, match_gt = distance, gt_idx
        if min_dist < dist_th:
            taken.add((sample, match_gt))
            g = gt[gt_by_sample[sample][match_gt]]
            tp.append(1)
            fp.append(0)
            conf.append(float(p["score"]))
            match["trans_err"].append(np.linalg.norm(np.array(p["translation"][:2]) - np.array(g["translation"][:2])))
            match["vel_err"].append(np.linalg.norm(np.array(p["velocity"]) - np.array(g["velocity"])))
            smallest = np.minimum(g["size"], p["size"])
            inter = np.prod(smallest)
            match["scale_err"].append(1 - inter / (np.prod(g["size"]) + np.prod(p["size"]) - inter))
            period = np.pi if class_name == "barrier" else 2 * np.pi
            match["orient_err"].append(abs(_angle_diff(float(quat_yaw(g["rotation"])), float(quat_yaw(p["rotation"])),
                                                       period)))
            acc = np.nan if g["attribute"] == NO_ATTRIBUTE else float(g["attribute"] == p["attribute"])
            match["attr_err"].append(1 - acc)
            match["conf"].append(float(p["score"]))
        else:
            tp.append(0)
            fp.append(1)
            conf.append(float(p["score"]))
    if len(match["trans_err"]) == 0:
        return MetricData.no_predictions()
    tp = np.cumsum(tp).astype(float)
    fp = np.cumsum(fp).astype(float)
    conf = np.array(conf)
    prec = tp / (fp + tp)
    rec = tp / float(npos)
    rec_interp = np.linspace(0, 1, NELEM)
    prec = np.interp(rec_interp, rec, prec, right=0)
    conf = np.interp(rec_interp, rec, conf, right=0)
    curves = {}
    for key in ("trans_err", "vel_err", "scale_err", "orient_err", "attr_err"):
        tmp = cummean(np.array(match[key]))
        curves[key] = np.interp(conf[::-1], match["conf"][::-1], tmp[::-1])[::-1]
    return MetricData(recall=rec_interp, precision=prec, confidence=conf, **curves)
