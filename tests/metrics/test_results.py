"""Results files: round trip, streaming, and one precise error per kind of mistake."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

import sianms_cli.metrics.results as results_module
from sianms_cli.errors import DataFormatError, OutputExistsError
from sianms_cli.metrics.boxes import make_boxes
from sianms_cli.metrics.results import (
    Results,
    ResultsFormatError,
    read_results,
    results_from_boxes,
    validate_results,
    write_results,
)

TOKENS = ("sample_a", "sample_b", "sample_c")


@pytest.fixture(autouse=True, params=["exact", "scanned"])
def reader(request, monkeypatch):
    """Every test reads through both paths: the exact reader, and the compiled scanner first
    (which hands any file it does not accept to the exact reader)."""
    if request.param == "scanned":
        monkeypatch.setattr(results_module, "SCAN_MIN_BYTES", 0)
    return request.param


def box(token: str, **fields) -> dict:
    return {"sample_token": token, "translation": [1.0, 2.0, 0.5], "size": [1.9, 4.5, 1.6],
            "rotation": [1.0, 0.0, 0.0, 0.0], "velocity": [0.5, -0.25], "detection_name": "car",
            "detection_score": 0.75, "attribute_name": "vehicle.moving", **fields}


def submission(**per_sample) -> dict:
    results = {token: [box(token)] for token in TOKENS}
    results.update(per_sample)
    return {"meta": {"use_camera": True, "use_lidar": False, "use_radar": False, "use_map": False,
                     "use_external": False}, "results": results}


def tables_equal(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and all(
        np.array_equal(a[name], b[name], equal_nan=a[name].dtype.kind == "f") for name in a.dtype.names)


def write(tmp_path, document, name="results.json") -> str:
    path = tmp_path / name
    path.write_text(document if isinstance(document, str) else json.dumps(document))
    return path


def test_read_gives_a_box_table_in_file_order(tmp_path):
    document = submission(sample_b=[box("sample_b", detection_name="pedestrian", attribute_name=""),
                                    box("sample_b", detection_score=1)], sample_c=[])
    results = read_results(write(tmp_path, document))
    assert results.sample_tokens == TOKENS
    assert results.boxes["sample"].tolist() == [0, 1, 1]
    assert results.boxes["label"].tolist() == [0, 5, 0]
    assert results.boxes["attribute"].tolist() == [5, -1, 5]
    assert results.boxes["score"].tolist() == [0.75, 0.75, 1.0]
    assert results.meta["use_camera"] is True


def test_write_then_read_is_exact_and_keeps_nan_velocities(tmp_path):
    rng = np.random.default_rng(0)
    count = 40
    yaw = rng.uniform(-3, 3, count)
    boxes = make_boxes(rng.integers(0, 3, count), rng.choice(["car", "barrier", "bicycle"], count),
                       rng.normal(0, 30, (count, 3)), rng.uniform(0.3, 5, (count, 3)),
                       np.c_[np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], rng.normal(0, 3, (count, 2)),
                       rng.random(count), rng.choice(["", "vehicle.parked", "cycle.with_rider"], count))
    boxes["velocity"][3] = np.nan
    original = results_from_boxes(TOKENS, boxes)
    path = write_results(tmp_path / "out" / "r.json", original)
    back = read_results(path)
    assert back.sample_tokens == TOKENS
    assert tables_equal(back.boxes, original.boxes)
    assert oct(os.stat(path).st_mode & 0o777) != "0o600"  # the umask's permissions, not mkstemp's


def test_write_refuses_to_clobber_and_writes_nothing_on_invalid_results(tmp_path):
    good = results_from_boxes(TOKENS, make_boxes(0, "car", [[0, 0, 0]], score=0.5))
    path = write_results(tmp_path / "r.json", good)
    with pytest.raises(OutputExistsError):
        write_results(path, good)
    write_results(path, good, overwrite=True)
    bad = results_from_boxes(TOKENS, make_boxes(0, "car", [[0, 0, 0]], score=1.5))
    with pytest.raises(ResultsFormatError, match="detection_score"):
        write_results(tmp_path / "bad.json", bad)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]


def test_streaming_across_chunk_boundaries(tmp_path, monkeypatch):
    document = submission(sample_a=[box("sample_a", translation=[float(i), 1e-7 * i, 12345.678901])
                                    for i in range(60)])
    path = write(tmp_path, json.dumps(document, indent=3))
    expected = read_results(path)
    for chunk in (1, 7, 64, 1000):
        monkeypatch.setattr(results_module, "_CHUNK_CHARS", chunk)
        monkeypatch.setattr(results_module, "_BATCH_BOXES", 5)
        again = read_results(path)
        assert again.sample_tokens == expected.sample_tokens
        assert tables_equal(again.boxes, expected.boxes)


def test_progress_reports_every_character(tmp_path):
    path = write(tmp_path, submission())
    seen = []
    read_results(path, progress=seen.append)
    assert sum(seen) == len(path.read_text())


@pytest.mark.parametrize(("field", "value", "message"), [
    ("translation", [1.0, 2.0], "list of 3 numbers"),
    ("translation", [1.0, "2", 3.0], "list of 3 numbers"),
    ("translation", [1.0, True, 3.0], "list of 3 numbers"),
    ("translation", [1.0, float("nan"), 3.0], "3 finite numbers"),
    ("size", [1.0, 0.0, 1.0], "3 positive numbers"),
    ("size", [1.0, -2.0, 1.0], "3 positive numbers"),
    ("rotation", [0.0, 0.0, 0.0, 0.0], "unit quaternion"),
    ("rotation", [0.7, 0.0, 0.0, 0.7], "unit quaternion"),
    ("velocity", [1.0, 2.0, 3.0], "list of 2 numbers"),
    ("velocity", [float("inf"), 0.0], "finite numbers or NaN"),
    ("detection_name", "cyclist", "unknown class 'cyclist'"),
    ("detection_name", None, "unknown class None"),
    ("detection_score", "0.5", "must be a number"),
    ("detection_score", 1.5, "in [0, 1]"),
    ("detection_score", float("nan"), "in [0, 1]"),
    ("attribute_name", "vehicle.flying", "unknown attribute"),
    ("sample_token", "sample_a", "not the sample it is listed under"),
])
def test_one_error_names_file_sample_box_and_field(tmp_path, field, value, message):
    document = submission(sample_b=[box("sample_b"), box("sample_b"), box("sample_b", **{field: value})])
    path = write(tmp_path, json.dumps(document))
    with pytest.raises(ResultsFormatError) as caught:
        read_results(path)
    error = caught.value
    assert (error.path, error.token, error.field, error.box_index) == (str(path), "sample_b", field, 2)
    assert message in str(error) and "box 2" in str(error)
    assert str(path) in str(error) and "\n" not in str(error)


def test_the_first_bad_box_in_file_order_is_reported(tmp_path):
    document = submission(sample_a=[box("sample_a"), box("sample_a", size=[0, 1, 1])],
                          sample_c=[box("sample_c", detection_name="cyclist")])
    with pytest.raises(ResultsFormatError) as caught:
        read_results(write(tmp_path, document))
    assert (caught.value.token, caught.value.box_index, caught.value.field) == ("sample_a", 1, "size")


@pytest.mark.parametrize("missing", ["sample_token", "translation", "velocity", "detection_score", "attribute_name"])
def test_a_missing_key_is_named(tmp_path, missing):
    entry = box("sample_c")
    del entry[missing]
    with pytest.raises(ResultsFormatError, match=f"field '{missing}': box 0: missing"):
        read_results(write(tmp_path, submission(sample_c=[entry])))


def test_extra_keys_such_as_num_pts_are_ignored(tmp_path):
    document = submission(sample_a=[box("sample_a", num_pts=0, ego_translation=[1, 2, 3])])
    assert len(read_results(write(tmp_path, document)).boxes) == 3


def test_too_many_boxes_in_a_sample(tmp_path):
    document = submission(sample_b=[box("sample_b")] * 4)
    with pytest.raises(ResultsFormatError, match="4 boxes; at most 3 per sample") as caught:
        read_results(write(tmp_path, document), max_boxes_per_sample=3)
    assert caught.value.token == "sample_b" and caught.value.box_index is None
    assert len(read_results(write(tmp_path, document, "ok.json")).boxes) == 6  # the default limit is 500


@pytest.mark.parametrize(("document", "message"), [
    ('{"meta": {}, "results": {"a": [], "a": []}}', "sample listed twice"),
    ('{"meta": {}}', "no 'results' object"),
    ('{"results": {}}', "no 'meta' object"),
    ('{"meta": [], "results": {}}', "field 'meta': must be an object"),
    ('{"meta": {"use_camera": 1}, "results": {}}', "field 'meta.use_camera': must be true or false"),
    ('{"meta": {"score_thr": NaN}, "results": {}}', "field 'meta.score_thr': not a finite number"),
    ('{"meta": {"x": {"y": [1, -Infinity]}}, "results": {}}', "field 'meta.x.y[1]': not a finite number"),
    ('{"meta": {}, "results": {"a": {}}}', "must be a list of boxes"),
    ('{"meta": {}, "results": {"a": [3]}}', "box 0: must be an object"),
    ('{"meta": {}, "results": []}', "expected '{' to open 'results'"),
    ('{"meta": {}, "meta": {}, "results": {}}', "field 'meta': field given twice"),
    ('{"meta": {}, "results": {}} []', "extra data after the top-level object"),
    ('{"meta": {},\n "results": {"a": [}}', "invalid JSON at line 2"),
    ('[]', "expected '{' to open the top-level object"),
    ('', "found 'the end of the file'"),
])
def test_malformed_documents(tmp_path, document, message):
    with pytest.raises(DataFormatError, match=message.replace("[", r"\[").replace("(", r"\(")):
        read_results(write(tmp_path, document))


def test_missing_file_and_other_top_level_fields(tmp_path):
    with pytest.raises(DataFormatError, match="results file not found"):
        read_results(tmp_path / "nope.json")
    with pytest.raises(DataFormatError, match="/dev/null: not a regular file, not a results file"):
        read_results("/dev/null")
    document = submission()
    document["extra"] = {"anything": [1, 2]}
    assert len(read_results(write(tmp_path, "\ufeff" + json.dumps(document))).boxes) == 3  # BOM too


def test_a_folder_is_not_a_results_file(tmp_path):
    with pytest.raises(DataFormatError) as caught:
        read_results(tmp_path)
    assert str(caught.value) == f"{tmp_path}: is a folder, not a results file"


def test_a_bad_score_prints_as_a_plain_number(tmp_path):
    # Not numpy's repr (np.float64(1.5)).
    path = write(tmp_path, submission(sample_c=[box("sample_c", detection_score=1.5)]))
    with pytest.raises(ResultsFormatError) as caught:
        read_results(path)
    assert str(caught.value) == (f"{path}: record sample_c: field 'detection_score': box 0: "
                                 "must be a number in [0, 1], got 1.5")


def test_validate_in_memory_results_names_the_box():
    boxes = make_boxes([0, 0, 1], "car", [[0, 0, 0], [1, 1, 1], [2, 2, 2]], score=0.5)
    boxes["rotation"][2] = [0.0, 0.0, 0.0, 2.0]
    with pytest.raises(ResultsFormatError) as caught:
        validate_results(Results(("x", "y"), boxes))
    assert (caught.value.token, caught.value.box_index, caught.value.field) == ("y", 0, "rotation")
    assert math.isclose(float(np.linalg.norm(boxes["rotation"][1])), 1.0)
