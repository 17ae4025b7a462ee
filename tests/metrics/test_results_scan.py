"""The compiled fast path for large results files: the same table to the bit as the exact
reader on every plain file, and None (the exact reader then reads) on anything else."""

from __future__ import annotations

import json

import numpy as np
import pytest

import sianms_cli.metrics.results as results_module
import sianms_cli.metrics.results_scan as scan_module
from sianms_cli.metrics.boxes import ATTRIBUTE_NAMES, DETECTION_NAMES
from sianms_cli.metrics.results import ResultsFormatError, read_results
from sianms_cli.metrics.results_scan import read_plain_results

KEYS = ("sample_token", "translation", "size", "rotation", "velocity", "detection_name",
        "detection_score", "attribute_name")


def random_document(samples: int = 40, seed: int = 0, tokens=None) -> dict:
    rng = np.random.default_rng(seed)
    tokens = tokens or [f"{rng.integers(1 << 62):032x}" for _ in range(samples)]
    results = {}
    for token in tokens:
        boxes = []
        for _ in range(int(rng.integers(0, 12))):
            yaw = rng.uniform(-np.pi, np.pi)
            boxes.append({
                "sample_token": token,
                "translation": (rng.normal(0, 500, 3)).tolist(),
                "size": [1, 2.5, float(np.float32(rng.uniform(0.3, 9)))],  # ints and float32 reprs
                "rotation": [float(np.cos(yaw / 2)), 0.0, 0, float(np.sin(yaw / 2))],
                "velocity": [float(rng.normal()), -0.0],
                "detection_name": str(rng.choice(DETECTION_NAMES)),
                "detection_score": round(float(rng.random()), int(rng.integers(1, 6))),
                "attribute_name": str(rng.choice(ATTRIBUTE_NAMES + ("",))),
            })
        results[token] = boxes
    return {"meta": {"use_camera": True, "use_lidar": False, "note": "x", "version": 1.5, "map": None},
            "results": results}


def exact(path):
    return results_module.read_results(path)  # SCAN_MIN_BYTES keeps small files on the exact path


def assert_same(plain, expected):
    assert plain is not None
    assert plain.boxes.flags.writeable
    assert plain.sample_tokens == expected.sample_tokens
    assert plain.boxes.tobytes() == expected.boxes.tobytes()
    assert plain.meta == expected.meta


@pytest.fixture
def small_chunks(monkeypatch):
    """Chunks of 12 boxes (a sample has at most 11 here), so small files go through every
    resume point."""
    monkeypatch.setattr(scan_module, "BOXES_PER_CHUNK", 12)


@pytest.mark.parametrize("dump", [
    lambda d: json.dumps(d),
    lambda d: json.dumps(d, indent=2),
    lambda d: json.dumps(d, separators=(",", ":")),
    lambda d: "\n\t " + json.dumps(d, indent="\t").replace(": ", " :\r\n ") + " \n",
])
def test_plain_files_give_the_exact_readers_table_to_the_bit(tmp_path, small_chunks, dump):
    path = tmp_path / "r.json"
    path.write_text(dump(random_document()))
    assert_same(read_plain_results(path), exact(path))


def test_key_order_within_a_box_does_not_matter(tmp_path, small_chunks):
    document = random_document(seed=1)
    rng = np.random.default_rng(2)
    for boxes in document["results"].values():
        boxes[:] = [{key: box[key] for key in rng.permutation(KEYS)} for box in boxes]
    path = tmp_path / "r.json"
    path.write_text(json.dumps(document))
    assert_same(read_plain_results(path), exact(path))


def test_numbers_convert_as_pythons_float(tmp_path):
    hard = ["0.1", "-0", "1E+2", "2.5e-3", "9007199254740993", "9007199254740992.5",
            "2.2250738585072011e-308", "4.9e-324", "1e-400", "1.7976931348623157e308",
            "0.30000001192092896", "123456789012345678901234567890", "7.0e22", "8.589973e9",
            "1.000000000000000111022302462515654042", "-12345.678901234567"]
    token = "t"
    boxes = ", ".join(
        f'{{"sample_token": "t", "translation": [{a}, {b}, 0], "size": [1, 1, 1], '
        f'"rotation": [1, 0, 0, 0], "velocity": [{b}, {a}], "detection_name": "car", '
        f'"detection_score": 0.5, "attribute_name": ""}}' for a, b in zip(hard, reversed(hard)))
    path = tmp_path / "r.json"
    path.write_text(f'{{"meta": {{}}, "results": {{"{token}": [{boxes}]}}}}')
    plain = read_plain_results(path)
    as_python = [float(value) if "." in value or "e" in value.lower() else float(int(value)) for value in hard]
    assert plain.boxes["translation"][:, 0].tolist() == as_python
    assert plain.boxes["velocity"][:, 0].tolist() == as_python[::-1]
    assert np.signbit(plain.boxes["translation"][1, 0]) == 0  # -0 is the integer 0
    assert_same(plain, exact(path))


def test_a_wrong_guess_of_the_middle_boundary_is_caught(tmp_path, small_chunks):
    """Tokens holding '}]' make the guessed split point fall inside a string: the second
    thread's work is dropped and the first reads on."""
    tokens = [f"tok}}] {i:04d}" for i in range(60)]
    path = tmp_path / "r.json"
    path.write_text(json.dumps(random_document(tokens=tokens)))
    middle = scan_module._member_boundary_after(np.fromfile(path, np.uint8), path.stat().st_size // 2)
    assert path.read_bytes()[middle - 2:middle + 2] == b"}] 0"  # inside a token: a wrong guess
    assert_same(read_plain_results(path), exact(path))


@pytest.mark.parametrize("change", [
    lambda text: text.replace('"velocity": [0.5, -0.25]', '"velocity": [NaN, -0.25]', 1),
    lambda text: text.replace('"detection_score"', '"num_pts": 3, "detection_score"', 1),
    lambda text: text.replace('"attribute_name": "vehicle.moving"',
                              '"attribute_name": "vehicle.moving", "size": [1, 1, 1]', 1),
    lambda text: text.replace('"sample_b"', '"sample\\u005fb"'),
    lambda text: text.replace('"sample_b"', '"sample_\u00e9"'),
    lambda text: "\ufeff" + text,
    lambda text: text.replace('{"meta"', '{"extra": 1, "meta"', 1),
    lambda text: text[:-1] + ', "extra": 1}',
    lambda text: text.replace("0.75", "0.75" + "0" * 40, 1),
    lambda text: text.replace("[1.0, 2.0, 0.5]", "[01.0, 2.0, 0.5]", 1),
    lambda text: text.replace("[1.0, 2.0, 0.5]", "[1.0, 2.0]", 1),
    lambda text: text.replace('"detection_name": "car"', '"detection_name": "cyclist"', 1),
    lambda text: text.replace('"sample_token": "sample_b"', '"sample_token": "sample_a"', 1),
    lambda text: text.replace("0.75", "1.5", 1),
    lambda text: text.replace('"meta": {', '"meta": {"nested": {}, ', 1),
    lambda text: "",
])
def test_anything_but_the_plain_form_or_a_valid_box_is_left_to_the_exact_reader(tmp_path, change):
    box = {"translation": [1.0, 2.0, 0.5], "size": [1.9, 4.5, 1.6], "rotation": [1.0, 0.0, 0.0, 0.0],
           "velocity": [0.5, -0.25], "detection_name": "car", "detection_score": 0.75,
           "attribute_name": "vehicle.moving"}
    document = {"meta": {"use_camera": True}, "results": {
        token: [{"sample_token": token, **box}] for token in ("sample_a", "sample_b")}}
    path = tmp_path / "r.json"
    path.write_text(change(json.dumps(document)), encoding="utf-8")
    assert read_plain_results(path) is None


def test_read_results_falls_back_with_the_exact_error_and_progress_adds_up(tmp_path, monkeypatch):
    document = random_document(samples=30, seed=3)
    last = next(token for token in reversed(document["results"]) if document["results"][token])
    document["results"][last][-1]["size"] = [1.0, -1.0, 1.0]
    path = tmp_path / "r.json"
    path.write_text(json.dumps(document))
    monkeypatch.setattr(scan_module, "BOXES_PER_CHUNK", 12)
    monkeypatch.setattr(results_module, "SCAN_MIN_BYTES", 0)
    seen = []
    with pytest.raises(ResultsFormatError, match="3 positive numbers") as caught:
        read_results(path, progress=seen.append)
    assert caught.value.token == last and caught.value.field == "size"
    assert sum(seen) <= path.stat().st_size


def test_progress_of_a_scanned_file_adds_up_to_its_size(tmp_path, monkeypatch):
    path = tmp_path / "r.json"
    path.write_text(json.dumps(random_document(samples=50), indent=1))
    monkeypatch.setattr(scan_module, "BOXES_PER_CHUNK", 12)
    monkeypatch.setattr(results_module, "SCAN_MIN_BYTES", 0)
    seen = []
    read_results(path, progress=seen.append)
    assert sum(seen) == path.stat().st_size and all(count > 0 for count in seen)


@pytest.mark.parametrize("results", ["{}", '{"a": [], "b": []}'])
def test_files_without_boxes(tmp_path, results):
    path = tmp_path / "r.json"
    path.write_text('{"meta": {"use_camera": true}, "results": ' + results + "}")
    assert_same(read_plain_results(path), exact(path))


def test_progress_adds_up_when_the_exact_reader_takes_over(tmp_path, monkeypatch):
    """A NaN velocity (valid, but not the plain form) stops the scanner late in the file; the
    exact reader then reads it all, and the progress it reports again is not counted twice."""
    document = random_document(samples=50, seed=4)
    last = next(token for token in reversed(document["results"]) if document["results"][token])
    document["results"][last][-1]["velocity"] = [float("nan"), 0.0]
    path = tmp_path / "r.json"
    path.write_text(json.dumps(document))
    monkeypatch.setattr(scan_module, "BOXES_PER_CHUNK", 12)
    monkeypatch.setattr(results_module, "SCAN_MIN_BYTES", 0)
    seen = []
    results = read_results(path, progress=seen.append)
    assert read_plain_results(path) is None and np.isnan(results.boxes["velocity"][-1, 0])
    assert sum(seen) == path.stat().st_size


def test_an_unexpected_error_surfaces_as_itself(tmp_path, monkeypatch):
    """Not as the map's 'cannot close exported pointers' (the traceback holds views of it)."""
    path = tmp_path / "r.json"
    path.write_text(json.dumps(random_document(samples=5)))

    def failing(buf, *args, **kwargs):
        view = buf[10:20]  # a view of the map, alive in the traceback
        raise RuntimeError(f"scanner failed after {view.nbytes} bytes")
    monkeypatch.setattr(scan_module, "_read_part", failing)
    with pytest.raises(RuntimeError, match="scanner failed"):
        read_plain_results(path)
