import numpy as np
import pytest

from sianms_cli.nuscenes import token_index
from sianms_cli.nuscenes.token_index import TokenIndex, _token_keys


def _hex_tokens(rng: np.random.Generator, count: int, width: int = 32) -> np.ndarray:
    digits = np.frombuffer(b"0123456789abcdef", np.uint8).astype(np.uint32)
    codes = np.ascontiguousarray(digits[rng.integers(0, 16, (count, width))])
    return codes.view(f"<U{width}").reshape(count)


def _reference_lookup(tokens: np.ndarray, queries: np.ndarray) -> list[int]:
    first_row = {}
    for row, token in enumerate(tokens.tolist()):
        first_row.setdefault(token, row)
    return [first_row.get(query, -1) for query in queries.tolist()]


def test_token_keys_do_not_depend_on_array_width():
    narrow = np.array(["abc", "d"])
    wide = np.array(["abc", "d", "x" * 41])
    assert _token_keys(narrow).tolist() == _token_keys(wide)[:2].tolist()
    assert len(set(_token_keys(wide).tolist())) == 3


@pytest.mark.parametrize("block", [7, 252, 1 << 16])
def test_lookup_matches_a_dictionary_with_misses_and_any_width(monkeypatch, block):
    monkeypatch.setattr(token_index, "_LOOKUP_BLOCK", block)
    rng = np.random.default_rng(0)
    tokens = _hex_tokens(rng, 500)
    misses = _hex_tokens(rng, 50)
    queries = np.concatenate([tokens[rng.integers(0, 500, 200)], misses, np.array(["", "a" * 40])])
    rng.shuffle(queries)
    index = TokenIndex(tokens)
    assert not index.by_string
    assert index.lookup(queries).tolist() == _reference_lookup(tokens, queries)
    assert index.lookup(queries.reshape(4, 63)).tolist() == np.reshape(
        _reference_lookup(tokens, queries), (4, 63)).tolist()
    # The width of the query array (here 40) is not the tokens' (32).
    assert queries.dtype == np.dtype("<U40")
    assert index.first_duplicate() is None


def test_lookup_keeps_the_queries_shape():
    index = TokenIndex(np.array(["a", "b", "c"]))
    assert index.lookup(np.array([["c", "a"], ["z", "b"]])).tolist() == [[2, 0], [-1, 1]]
    assert index.lookup(np.array([], dtype=str)).shape == (0,)
    assert index.lookup(np.array([], dtype=str)).dtype == np.int64
    assert TokenIndex(np.array([], dtype=str)).lookup(np.array(["a"])).tolist() == [-1]


def test_a_hit_is_confirmed_against_the_token(monkeypatch):
    # Keys that tell the tokens apart but give a different query the key of "bb".
    monkeypatch.setattr(token_index, "_token_keys",
                        lambda tokens: np.char.str_len(tokens).astype(np.uint64))
    index = TokenIndex(np.array(["a", "bb", "ccc"]))
    assert not index.by_string
    assert index.lookup(np.array(["xx", "bb", "cccc"])).tolist() == [-1, 1, -1]


def test_token_index_falls_back_to_strings_on_key_collisions(monkeypatch):
    monkeypatch.setattr(token_index, "_token_keys", lambda tokens: np.zeros(len(tokens), np.uint64))
    monkeypatch.setattr(token_index, "_LOOKUP_BLOCK", 2)
    tokens = np.array(["b", "a", "c", "a"])
    index = TokenIndex(tokens)
    assert index.by_string
    assert index.lookup(np.array(["c", "b", "z"])).tolist() == [2, 0, -1]
    assert index.first_duplicate() == (1, 3)
    assert TokenIndex(np.array(["x", "y"])).first_duplicate() is None


@pytest.mark.parametrize("tokens, duplicate", [
    (["a", "b", "c", "b", "a"], (1, 3)),  # "b" is seen twice first (row 3), before "a" (row 4)
    (["x", "y", "x", "x"], (0, 2)),
    (["p", "q", "r"], None),
])
def test_first_duplicate_in_row_order(tokens, duplicate):
    index = TokenIndex(np.array(tokens))
    assert index.first_duplicate() == duplicate
    assert index.by_string == (duplicate is not None)
    # A duplicated token is found at its first row.
    assert index.lookup(np.array(tokens)).tolist() == _reference_lookup(np.array(tokens), np.array(tokens))
