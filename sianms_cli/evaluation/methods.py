"""Which boxes each duplicate-handling method reports (docs/methods.md#duplicate-handling).

The per-scene stage (:mod:`.scene`) computes every box any method can report: one per kept
detection (``single``) and one per siaNMS or oracle match. A method is then a selection:

- ``vanilla``: every single-camera box (the paper's first row);
- ``axis-nms`` / ``rotated-nms`` / ``circle-nms``: greedy BEV NMS of the single-camera boxes,
  per sample and class (:mod:`.nms`), at an IoU threshold (or CenterPoint's per-class radius);
- ``sianms``: the single-camera boxes of detections no kept match took, plus one box per
  kept match;
- ``hybrid``: siaNMS, then the paper's NMS (axis-aligned, IoU 0.3) on what remains;
- ``gated-sianms`` (ours, not the paper's): siaNMS keeping a match only where its two
  detections' own single-camera boxes overlap in bird's-eye view (:func:`gate_passed`); the
  detections of a refused match report their single-camera boxes;
- ``oracle``: as ``sianms`` with ground-truth identity as the matcher.

Names carry their setting: ``axis-nms@0.1`` is axis-aligned NMS at IoU 0.1; a plain
``axis-nms`` is the paper's 0.3.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sianms_cli.errors import SianmsError
from sianms_cli.geometry.bev import rotated_iou_pairs

VANILLA, AXIS_NMS, ROTATED_NMS, CIRCLE_NMS = "vanilla", "axis-nms", "rotated-nms", "circle-nms"
SIANMS, HYBRID, GATED_SIANMS, ORACLE = "sianms", "hybrid", "gated-sianms", "oracle"
METHODS = (VANILLA, AXIS_NMS, ROTATED_NMS, CIRCLE_NMS, SIANMS, HYBRID, GATED_SIANMS, ORACLE)
MATCHERS = (SIANMS, GATED_SIANMS, ORACLE)  # the methods that report one box per kept cross-camera match
IOU_METHODS = (AXIS_NMS, ROTATED_NMS)
PAPER_NMS_IOU = 0.3  # paper §V-B: greedy axis-aligned BEV NMS at IoU 0.3


@dataclass(frozen=True, eq=False)
class AllBoxes:
    """Every box of an evaluation as columns (B rows), read from the scenes' boxes tables.

    Attributes:
        sample: (B,) int64 index into the evaluation's sample tokens.
        kind: (B,) str ``single``, ``sianms`` or ``oracle``.
        detection_a, detection_b: (B,) str ids ("" for a single box's b).
        classes: (B,) str; score: (B,) float64;
        translation: (B, 3), size: (B, 3) (w, l, h), yaw: (B,), NaN for a dismissed match.
        dismissed: (B,) bool; correct: (B,) bool, a match of one ground-truth instance (scoring only).
        wedges: (B, 12) a match's two frustum wedges, global (x, y) of 3 corners each; NaN for a single box.
    """

    sample: np.ndarray
    kind: np.ndarray
    detection_a: np.ndarray
    detection_b: np.ndarray
    classes: np.ndarray
    score: np.ndarray
    translation: np.ndarray
    size: np.ndarray
    yaw: np.ndarray
    dismissed: np.ndarray
    correct: np.ndarray
    wedges: np.ndarray


def parse_methods(text: str, nms_sweep: tuple[float, ...] = ()) -> tuple[str, ...]:
    """The method names of ``--methods`` ("all" or a comma list), the NMS sweep's variants added.

    Each IoU-based NMS asked for is run at the paper's 0.3 and at every sweep threshold
    (``axis-nms@0.05`` ...).
    """
    names = METHODS if text.strip() == "all" else tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [name for name in names if name not in METHODS]
    if unknown or not names:
        raise SianmsError(f"--methods: unknown method {', '.join(unknown) or '(none)'}; expected 'all' or "
                          f"a comma list of {', '.join(METHODS)}")
    out: list[str] = []
    for name in dict.fromkeys(names):
        out.append(name)
        if name in IOU_METHODS:  # a method is its label: 0.1 and 0.10 are one, 0.30 is the paper's own
            labels = dict.fromkeys(f"{t:g}" for t in nms_sweep)
            out += [f"{name}@{label}" for label in labels if label != f"{PAPER_NMS_IOU:g}"]
    return tuple(out)


def parse_thresholds(text: str | None) -> tuple[float, ...]:
    """``--nms-sweep 0.05,0.1``: IoU thresholds in (0, 1)."""
    if not text:
        return ()
    try:
        values = tuple(float(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise SianmsError(f"--nms-sweep: expected comma-separated numbers, got '{text}'") from None
    if not all(0 < value < 1 for value in values):
        raise SianmsError(f"--nms-sweep: every IoU threshold must be in (0, 1), got '{text}'")
    return values


def split_name(method: str) -> tuple[str, float | None]:
    """``axis-nms@0.1`` -> (``axis-nms``, 0.1); ``axis-nms`` -> (``axis-nms``, 0.3); others (name, None)."""
    base, _, threshold = method.partition("@")
    if threshold:
        return base, float(threshold)
    return base, PAPER_NMS_IOU if base in IOU_METHODS else None


def nms_keep(boxes: AllBoxes, rows: np.ndarray, kind: str, threshold: float | None, axis_mode: str) -> np.ndarray:
    """The subset of ``rows`` an NMS keeps, per sample and class; sorted."""
    from sianms_cli.evaluation import nms

    if len(rows) == 0:
        return rows
    names, class_index = np.unique(boxes.classes[rows], return_inverse=True)
    label = boxes.sample[rows] * len(names) + class_index  # boxes of other samples or classes never suppress
    centers, sizes, yaw, scores = (boxes.translation[rows, :2], boxes.size[rows, :2], boxes.yaw[rows],
                                   boxes.score[rows])
    if kind in IOU_METHODS:  # method_threshold gives each its IoU threshold
        assert threshold is not None, kind
        kept = (nms.axis_nms(centers, sizes, yaw, scores, label, threshold, mode=axis_mode) if kind == AXIS_NMS
                else nms.rotated_nms(centers, sizes, yaw, scores, label, threshold))
    else:
        kept = nms.circle_nms(centers, scores, label, np.array([nms.CIRCLE_RADIUS_M[n] for n in names])[class_index])
    return np.sort(rows[np.asarray(kept, dtype=np.int64)])


def single_rows(boxes: AllBoxes, detections: np.ndarray) -> np.ndarray:
    """The row of each detection's single-camera box; -1 for a detection without one."""
    singles = np.flatnonzero(boxes.kind == "single")
    order = np.argsort(boxes.detection_a[singles])
    ids = boxes.detection_a[singles][order]
    if len(ids) == 0:
        return np.full(len(detections), -1, dtype=np.int64)
    position = np.minimum(np.searchsorted(ids, detections), len(ids) - 1)
    return np.where(ids[position] == detections, singles[order][position], -1)


def match_singles(boxes: AllBoxes, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The single-camera box rows of each match row's two detections (-1 where one has none)."""
    both = single_rows(boxes, np.concatenate([boxes.detection_a[rows], boxes.detection_b[rows]]))
    return both[:len(rows)], both[len(rows):]


def bev_boxes(boxes: AllBoxes, rows: np.ndarray) -> np.ndarray:
    """(len(rows), 5) bird's-eye-view boxes (x, y, width, length, yaw) of ``rows``."""
    return np.column_stack([boxes.translation[rows, :2], boxes.size[rows, :2], boxes.yaw[rows]])


def gate_passed(boxes: AllBoxes, rows: np.ndarray) -> np.ndarray:
    """(len(rows),) bool: the two detections of each match row have single-camera boxes that
    overlap in bird's-eye view (rotated IoU > 0).

    Two distinct cars cannot share ground, so two detections whose own 3-D boxes lie apart
    are two objects whatever their embeddings say; the gate has no parameter to tune.
    """
    a, b = match_singles(boxes, rows)
    both = (a >= 0) & (b >= 0)
    passed = np.zeros(len(rows), dtype=bool)
    passed[both] = rotated_iou_pairs(bev_boxes(boxes, a[both]), bev_boxes(boxes, b[both])) > 0
    return passed


def match_kind(matcher: str) -> str:
    """The kind of the match rows ``matcher`` chooses from: the gate chooses among siaNMS's."""
    return SIANMS if matcher == GATED_SIANMS else matcher


def kept_matches(boxes: AllBoxes, matcher: str) -> np.ndarray:
    """(B,) bool: the match rows ``matcher`` (one of :data:`MATCHERS`) keeps."""
    kept = (boxes.kind == match_kind(matcher)) & ~boxes.dismissed
    if matcher == GATED_SIANMS:
        rows = np.flatnonzero(kept)
        kept[rows] = gate_passed(boxes, rows)
    return kept


def merged_selection(boxes: AllBoxes, matcher: str) -> np.ndarray:
    """Rows of a matcher's method: its kept matches, and the single boxes none of them took."""
    kept_match = kept_matches(boxes, matcher)
    taken = np.concatenate([boxes.detection_a[kept_match], boxes.detection_b[kept_match]])
    single = (boxes.kind == "single") & ~np.isin(boxes.detection_a, taken)
    return np.flatnonzero(single | kept_match)


def select(boxes: AllBoxes, method: str, axis_mode: str = "ignore-yaw") -> np.ndarray:
    """Rows of ``boxes`` that ``method`` reports (module docstring), sorted."""
    base, threshold = split_name(method)
    singles = np.flatnonzero(boxes.kind == "single")
    if base == VANILLA:
        return singles
    if base in (AXIS_NMS, ROTATED_NMS, CIRCLE_NMS):
        return nms_keep(boxes, singles, base, threshold, axis_mode)
    if base in MATCHERS:
        return merged_selection(boxes, base)
    if base == HYBRID:
        return nms_keep(boxes, merged_selection(boxes, SIANMS), AXIS_NMS, PAPER_NMS_IOU, axis_mode)
    raise SianmsError(f"unknown method '{method}'")
