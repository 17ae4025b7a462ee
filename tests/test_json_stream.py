"""Streaming JSON: arrays decoded in runs of elements, objects walked key by key."""

import json
import math

import pytest

from sianms_cli.errors import DataFormatError
from sianms_cli.io import read_json
from sianms_cli.json_stream import (
    JsonStream,
    array_pieces,
    is_number,
    json_kind,
    record_runs,
    types_within,
)

# Elements whose text holds the "}, {" a cut is guessed at, inside strings and nested objects.
TRICKY_ELEMENTS = [
    {"token": "a", "name": "}, {", "nested": {"x": [{"y": 1}, {"z": "}, {"}]}},
    {"token": "b", "escaped": "quote \" and }, {\"k\": 1}", "empty": [], "none": None},
    {"token": "c", "unicode": "caf\u00e9 \u2014 \U0001f697", "numbers": [0, -1.5, 1e-7, 2**62]},
    {},
    {"token": "d", "deep": {"a": {"b": {"c": {}}}}, "flag": True},
] * 3


def _write(tmp_path, text, name="doc.json"):
    path = tmp_path / name
    path.write_bytes(text.encode("utf-8") if isinstance(text, str) else text)
    return path


def _stream_document(path, chunk_chars):
    """The top-level object at ``path``, read with JsonStream: nested objects item by item."""
    document = {}
    with JsonStream(path, chunk_chars=chunk_chars) as stream:
        for key in stream.object_keys():
            if key.startswith("object"):
                document[key] = dict(stream.object_items(key))
            else:
                document[key] = stream.value()
    return document


def _stream_error(path, chunk_chars):
    with pytest.raises(DataFormatError) as caught:
        _stream_document(path, chunk_chars)
    return str(caught.value)


# --------------------------------------------------------------------------- value helpers


@pytest.mark.parametrize("value, kind", [
    ({}, "an object"), ([], "a list"), ("", "a string"), (True, "a boolean"), (0, "a number"),
    (1.5, "a number"), (None, "null"), ((1, 2), "tuple"),
])
def test_json_kind(value, kind):
    assert json_kind(value) == kind


def test_is_number_and_types_within():
    assert [is_number(v) for v in (1, 1.5, True, "1", None, float("nan"))] == [
        True, True, False, False, False, True]
    assert types_within([1, 2.0], (int, float))
    assert not types_within([1, True], (int,))
    assert types_within([], (str,))
    assert types_within(iter(["a", "b"]), (str,))


# --------------------------------------------------------------------------- record runs


def test_record_runs_cover_the_array_even_when_guessed_cuts_are_wrong(tmp_path):
    elements = [{"b": {"c": 1}}, {"d": [1, 2]}, 7, {"a": "}, {"}, {"e": "x"}]
    text = json.dumps(elements).encode()
    runs = record_runs(text, 1)
    assert [text[begin:end] for begin, end in runs] == [
        b'{"b": {"c": 1}}', b'{"d": [1, 2]}, 7, {"a": "}', b'{"}', b'{"e": "x"}']
    path = _write(tmp_path, text + b"\n")
    pieces = list(array_pieces(path, 1))
    # The second run ends inside a string and fails: the rest comes from a whole decode.
    assert pieces == [elements[:1], elements[1:]]


@pytest.mark.parametrize("text", ['{"a": [1]}', "[1, 2] x", "x [1]", "", "  "])
def test_record_runs_need_one_array(text):
    assert record_runs(text.encode(), 1) is None


@pytest.mark.parametrize("text", ["[]", " [ \n ] \n", "[\n]"])
def test_empty_arrays(tmp_path, text):
    runs = record_runs(text.encode(), 1)
    assert len(runs) == 1
    begin, end = runs[0]
    assert json.loads(b"[" + text.encode()[begin:end] + b"]") == []
    path = _write(tmp_path, text)
    assert list(array_pieces(path, 1)) == [[]]
    assert list(array_pieces(path, 1000)) == [[]]


@pytest.mark.parametrize("chunk_bytes", [1, 40, 97, 300, 10_000])
@pytest.mark.parametrize("indent", [None, 2])
def test_an_array_in_pieces_decodes_as_the_whole(tmp_path, chunk_bytes, indent):
    path = _write(tmp_path, json.dumps(TRICKY_ELEMENTS, indent=indent, ensure_ascii=False))
    pieces = list(array_pieces(path, chunk_bytes))
    assert [element for piece in pieces for element in piece] == read_json(path) == TRICKY_ELEMENTS
    if chunk_bytes >= path.stat().st_size:
        assert len(pieces) == 1


def test_cuts_inside_strings_and_nested_objects_are_recovered(tmp_path):
    text = json.dumps(TRICKY_ELEMENTS)
    runs = record_runs(text.encode(), 1)
    decodable = []
    for begin, end in runs:
        try:
            json.loads(b"[" + text.encode()[begin:end] + b"]")
            decodable.append(True)
        except json.JSONDecodeError:
            decodable.append(False)
    assert not all(decodable)  # some guessed cuts are wrong ...
    path = _write(tmp_path, text)
    pieces = list(array_pieces(path, 1))
    assert [element for piece in pieces for element in piece] == TRICKY_ELEMENTS  # ... yet all comes back


def test_values_only_the_json_module_reads_come_back_in_pieces(tmp_path):
    path = _write(tmp_path, '[{"a": 1}, {"b": NaN}, {"c": 3}]')
    elements = [element for piece in array_pieces(path, 1) for element in piece]
    assert elements[0] == {"a": 1} and math.isnan(elements[1]["b"]) and elements[2] == {"c": 3}


def test_a_file_that_is_not_an_array_comes_whole(tmp_path):
    path = _write(tmp_path, '{"records": [{"a": 1}, {"b": 2}]}')
    assert list(array_pieces(path, 1)) == [{"records": [{"a": 1}, {"b": 2}]}]


@pytest.mark.parametrize("text", [
    "  [1, 2] [3]", "[1, 2]]", '[{"a": 1},\n {"b": 2},,\n {"c": 3}]', '[{"a": 1}, {"b": 2},]',
    '[{"a": 1},\n {"b": tru},\n {"c": 3}]', '{"a": 1',
])
def test_malformed_arrays_fail_in_pieces_as_they_fail_whole(tmp_path, text):
    path = _write(tmp_path, text)
    with pytest.raises(DataFormatError) as whole:
        read_json(path)
    with pytest.raises(DataFormatError) as in_pieces:
        list(array_pieces(path, 1))
    assert str(in_pieces.value) == str(whole.value)
    assert str(whole.value).startswith(f"{path}: invalid JSON at line")


def test_a_syntax_error_names_its_line_and_column_in_pieces(tmp_path):
    path = _write(tmp_path, '[{"a": 1},\n {"b": 2},\n {"c": [1, }]')
    with pytest.raises(DataFormatError) as caught:
        list(array_pieces(path, 1))
    assert str(caught.value) == f"{path}: invalid JSON at line 3, column 12: Expecting value"


def test_invalid_utf8_in_pieces(tmp_path):
    path = _write(tmp_path, b'[{"a": 1}, {"b": "\xff"}]')
    with pytest.raises(DataFormatError) as caught:
        list(array_pieces(path, 1))
    assert str(caught.value) == f"{path}: not valid UTF-8 at byte 18"


# --------------------------------------------------------------------------- JsonStream


DOCUMENT = {
    "meta": {"use_camera": True, "note": "}] inside a string"},
    "object_a": {
        "plain": [{"x": [1.5, -2, 3e-7]}, {"y": "}]"}],
        "esc\"aped \u00e9 key": [],
        "nested": [{"deep": {"list": [[], [{}]]}}],
        "number": 12345678901234567890,
        "empty object": {},
    },
    "object_empty": {},
    "list": ["}]", {"k": "}, {"}, None, False],
    "last": 0.1,
}


@pytest.mark.parametrize("chunk_chars", [1, 2, 7, 64, 1 << 20])
@pytest.mark.parametrize("indent", [None, 3])
def test_stream_decodes_as_the_whole_at_any_chunk_size(tmp_path, chunk_chars, indent):
    path = _write(tmp_path, json.dumps(DOCUMENT, indent=indent, ensure_ascii=False))
    assert _stream_document(path, chunk_chars) == DOCUMENT


@pytest.mark.parametrize("chunk_chars", [1, 5, 1 << 20])
def test_stream_reads_nan_and_byte_order_marks(tmp_path, chunk_chars):
    path = _write(tmp_path, '\ufeff{"list": [{"v": NaN}, {"v": 1}], "object_x": {"a": [NaN]}}')
    document = _stream_document(path, chunk_chars)
    assert math.isnan(document["list"][0]["v"]) and document["list"][1] == {"v": 1}
    assert math.isnan(document["object_x"]["a"][0])


def test_progress_counts_every_character(tmp_path):
    path = _write(tmp_path, json.dumps(DOCUMENT, ensure_ascii=False))
    seen = []
    with JsonStream(path, chunk_chars=10, progress=seen.append) as stream:
        for _ in stream.object_keys():
            stream.value()
    assert sum(seen) == len(path.read_text(encoding="utf-8")) and max(seen) >= 10


@pytest.mark.parametrize("chunk_chars", [1, 3, 1 << 20])
@pytest.mark.parametrize("text, line, column, message", [
    ('{"a": [1,\n 2,, 3]}', 2, 4, "Expecting value"),
    ('{"a": 1,\n  "b" 2}', 2, 7, "expected ':' after a key, found '2'"),
    ('{"object_a": {"x": 1\n "y": 2}}', 2, 2, "expected ',' or '}' in 'object_a', found '\"'"),
    ('{"a": {"x": 1\n "y": 2}}', 2, 2, "Expecting ',' delimiter"),
    ('{"a": 1,\n 7: 2}', 2, 2, "expected a string key in the top-level object"),
    ('{"a": 1} \n [2]', 2, 2, "extra data after the top-level object"),
    ('[1]', 1, 1, "expected '{' to open the top-level object, found '['"),
    ('{"a": [1, 2', 1, 12, "Expecting ',' delimiter"),
    ('\n\n', 3, 1, "expected '{' to open the top-level object, found 'the end of the file'"),
    ('{"a": ' + '[' * 5000 + ']' * 5000 + '}', 1, 7, "nested deeper than 1024 levels"),
])
def test_stream_errors_name_line_and_column(tmp_path, chunk_chars, text, line, column, message):
    path = _write(tmp_path, text)
    assert _stream_error(path, chunk_chars) == (
        f"{path}: invalid JSON at line {line}, column {column}: {message}")


def test_stream_syntax_errors_match_the_json_module(tmp_path):
    text = '{"meta": {},\n "results": {\n  "a": [{"x": 1}],\n  "b": [{"x": 2},, {"x": 3}]}}'
    path = _write(tmp_path, text)
    with pytest.raises(json.JSONDecodeError) as reference:
        json.loads(text)
    expected = (f"{path}: invalid JSON at line {reference.value.lineno}, "
                f"column {reference.value.colno}: {reference.value.msg}")
    for chunk_chars in (1, 4, 1 << 20):
        with pytest.raises(DataFormatError) as caught:
            with JsonStream(path, chunk_chars=chunk_chars) as stream:
                for key in stream.object_keys():
                    if key == "results":
                        list(stream.object_items(key))
                    else:
                        stream.value()
        assert str(caught.value) == expected


def test_stream_duplicate_top_level_key_invalid_utf8_and_missing_file(tmp_path):
    path = _write(tmp_path, '{"a": 1, "a": 2}')
    assert _stream_error(path, 4) == f"{path}: field 'a': field given twice"
    path = _write(tmp_path, b'{"a": "\xff"}', "bad.json")
    assert _stream_error(path, 4).startswith(f"{path}: not valid UTF-8 (")
    missing = tmp_path / "missing.json"
    assert _stream_error(missing, 4) == f"{missing}: cannot open: No such file or directory"
