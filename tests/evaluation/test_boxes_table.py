"""The per-scene boxes table of `sianms eval` (`evaluation/scene.py` writes it, `evaluation/finish.py`
reads it): its vectors go through Parquet with their nulls, in a form every supported pyarrow reads."""

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from sianms_cli.errors import DataFormatError
from sianms_cli.evaluation.finish import read_boxes
from sianms_cli.evaluation.scene import BOXES_SCHEMA, vector_column

TRANSLATION = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]])
VALID = np.array([True, False, True])  # the middle box: a dismissed match, no box


def boxes_table(translation: pa.Array) -> pa.Table:
    """Three boxes of sample s0, the middle one with no translation, size or yaw."""
    return pa.table({
        "scene_token": ["scene"] * 3, "sample_token": ["s0"] * 3, "kind": ["single", "sianms", "sianms"],
        "detection_a": ["a", "b", "c"], "detection_b": [None, "d", "e"], "camera_a": ["CAM_FRONT"] * 3,
        "camera_b": [None, "CAM_FRONT_LEFT", "CAM_FRONT_LEFT"], "class": ["car"] * 3,
        "score": pa.array([0.9, 0.8, 0.7], pa.float32()), "distance": pa.array([None, 0.5, 0.4], pa.float32()),
        "dismissed": [False, True, False], "correct": [None, True, False],
        "num_points": pa.array([9, 0, 7], pa.int32()),
        "translation": translation, "size": vector_column(TRANSLATION + 1, VALID),
        "yaw": [0.1, None, 0.3],
        "wedges": vector_column(np.arange(36.0).reshape(3, 12), np.array([False, True, True])),
    }, schema=BOXES_SCHEMA)


def test_a_null_vector_holds_no_values():
    column = vector_column(TRANSLATION, VALID)
    assert column.to_pylist() == [[1.0, 2.0, 3.0], None, [7.0, 8.0, 9.0]]
    assert len(column.values) == 6  # pyarrow 19-24 refuse to write a null list that holds values


def test_boxes_round_trip_through_parquet_with_their_nulls(tmp_path):
    path = tmp_path / "scene.parquet"
    pq.write_table(boxes_table(vector_column(TRANSLATION, VALID)), path)
    boxes = read_boxes([path], ["s0"])
    np.testing.assert_array_equal(boxes.translation[VALID], TRANSLATION[VALID])
    np.testing.assert_array_equal(boxes.size[VALID], TRANSLATION[VALID] + 1)
    assert np.isnan(boxes.translation[1]).all() and np.isnan(boxes.size[1]).all() and np.isnan(boxes.yaw[1])
    assert np.isnan(boxes.wedges[0]).all()
    np.testing.assert_array_equal(boxes.wedges[2], np.arange(24.0, 36.0))


def test_a_vector_of_the_wrong_length_is_named(tmp_path):
    path = tmp_path / "scene.parquet"
    short = pa.array([[1.0, 2.0, 3.0], None, [7.0, 8.0]], pa.list_(pa.float64()))
    pq.write_table(boxes_table(short), path)
    with pytest.raises(DataFormatError, match="translation holds 2 values, not 3"):
        read_boxes([path], ["s0"])
