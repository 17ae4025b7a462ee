"""siaNMS's re-identification figures, what its wrong matches had to choose from, and the gated variant."""

import numpy as np

from sianms_cli.evaluation.finish import reidentification
from sianms_cli.evaluation.methods import gate_passed, select, single_rows

from box_rows import all_boxes


def test_wrong_matches_are_split_by_whether_a_true_partner_was_there():
    boxes = all_boxes([
        ("oracle", "a1", "b1", False, True),  # the true pairs: a1-b1, a2-b2, a3-b3
        ("oracle", "a2", "b2", False, True),
        ("oracle", "a3", "b3", True, True),
        ("sianms", "a1", "b1", False, True),
        ("sianms", "a2", "b9", False, False),  # a2 had its partner b2 and was matched to b9
        ("sianms", "a8", "b2", False, False),  # b2's partner a2 was there: passed over too
        ("sianms", "a7", "b7", False, False),  # neither a7 nor b7 is in a true pair
        ("sianms", "a6", "b6", True, False),  # dismissed: not a kept match
        ("sianms", "a3", "b3", True, True),  # a right pair the frustum test dismissed
    ])
    reid = reidentification(boxes)
    sianms = reid["sianms"]
    assert (sianms["pairs_matched"], sianms["pairs_correct"], sianms["pairs_true"]) == (4, 1, 3)
    assert sianms["precision"] == 0.25 and sianms["recall"] == 1 / 3
    assert (sianms["wrong_without_partner"], sianms["wrong_partner_passed_over"]) == (1, 2)
    assert (sianms["dismissed"], sianms["dismissed_right"]) == (2, 1)
    oracle = reid["oracle"]
    assert (oracle["pairs_matched"], oracle["wrong_without_partner"], oracle["wrong_partner_passed_over"]) == (2, 0, 0)
    assert (oracle["dismissed"], oracle["dismissed_right"]) == (1, 1)


# Single-camera boxes: a1/b1 one car seen twice (0.5 m apart), a2/b2 one car whose two boxes
# missed each other (6 m apart), a3 and b3 two cars of a parked row (one length apart, touching:
# no shared area).
GATE_SCENE = [
    ("single", "a1", "", False, False, (10.0, 0.0)), ("single", "b1", "", False, False, (10.5, 0.0)),
    ("single", "a2", "", False, False, (20.0, 5.0)), ("single", "b2", "", False, False, (20.0, 11.0)),
    ("single", "a3", "", False, False, (30.0, 0.0)), ("single", "b3", "", False, False, (30.0, 1.8)),
    ("oracle", "a1", "b1", False, True, (10.2, 0.0)), ("oracle", "a2", "b2", False, True, (20.0, 8.0)),
    ("sianms", "a1", "b1", False, True, (10.2, 0.0)), ("sianms", "a2", "b2", False, True, (20.0, 8.0)),
    ("sianms", "a3", "b3", False, False, (30.0, 0.9)),
]


def test_the_gate_keeps_only_matches_whose_single_camera_boxes_share_ground():
    boxes = all_boxes(GATE_SCENE)
    match_rows = np.flatnonzero(boxes.kind == "sianms")
    assert gate_passed(boxes, match_rows).tolist() == [True, False, False]
    assert single_rows(boxes, np.array(["b3", "a1", "zz"])).tolist() == [5, 0, -1]
    reported = select(boxes, "gated-sianms")
    assert boxes.detection_a[reported].tolist() == ["a2", "b2", "a3", "b3", "a1"]  # a1-b1 merged, the rest single
    assert boxes.kind[reported].tolist() == ["single"] * 4 + ["sianms"]
    assert len(select(boxes, "sianms")) == 3  # every match kept: three merged boxes, no single one
    reid = reidentification(boxes, gated=True)
    gated = reid["gated-sianms"]
    assert (gated["pairs_matched"], gated["pairs_correct"], gated["pairs_true"]) == (1, 1, 2)
    assert (gated["gate_refused"], gated["gate_refused_right"], gated["wrong_without_partner"]) == (2, 1, 0)
    assert (reid["sianms"]["wrong_without_partner"], "gate_refused" in reid["sianms"]) == (1, False)
    assert "gated-sianms" not in reidentification(boxes)


def test_a_match_whose_detection_has_no_single_box_fails_the_gate():
    boxes = all_boxes([("single", "a1", "", False, False), ("sianms", "a1", "b9", False, False)])
    assert gate_passed(boxes, np.array([1])).tolist() == [False]
    assert gate_passed(all_boxes(GATE_SCENE[6:]), np.array([2])).tolist() == [False]  # no single box at all
