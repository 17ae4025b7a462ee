"""siaNMS's re-identification figures, and what its wrong matches had to choose from."""

import numpy as np

from sianms_cli.pipelines.finish import reidentification
from sianms_cli.pipelines.methods import AllBoxes


def matches(rows: list[tuple[str, str, str, bool, bool]]) -> AllBoxes:
    """AllBoxes of (kind, detection_a, detection_b, dismissed, correct) rows; the geometry is irrelevant here."""
    kind, a, b, dismissed, correct = (np.array(column) for column in zip(*rows))
    count = len(rows)
    return AllBoxes(sample=np.zeros(count, np.int64), kind=kind, detection_a=a, detection_b=b,
                    classes=np.full(count, "car"), score=np.ones(count), translation=np.zeros((count, 3)),
                    size=np.ones((count, 3)), yaw=np.zeros(count), dismissed=dismissed.astype(bool),
                    correct=correct.astype(bool), wedges=np.full((count, 12), np.nan))


def test_wrong_matches_are_split_by_whether_a_true_partner_was_there():
    boxes = matches([
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
