"""Hand-written rows of an evaluation's boxes as :class:`~sianms_cli.evaluation.methods.AllBoxes`."""

import numpy as np

from sianms_cli.evaluation.methods import AllBoxes


def all_boxes(rows: list[tuple]) -> AllBoxes:
    """AllBoxes of (kind, detection_a, detection_b, dismissed, correct[, (x, y)]) rows, one sample:
    cars 1.8 m wide and 4.6 m long along x, at (0, 0) where no place is given."""
    rows = [row if len(row) == 6 else (*row, (0.0, 0.0)) for row in rows]
    kind, a, b, dismissed, correct, xy = (np.array(column) for column in zip(*rows))
    count = len(rows)
    return AllBoxes(sample=np.zeros(count, np.int64), kind=kind, detection_a=a, detection_b=b,
                    classes=np.full(count, "car"), score=np.ones(count),
                    translation=np.column_stack([xy, np.zeros(count)]), size=np.tile([1.8, 4.6, 1.5], (count, 1)),
                    yaw=np.zeros(count), dismissed=dismissed.astype(bool), correct=correct.astype(bool),
                    wedges=np.full((count, 12), np.nan))
