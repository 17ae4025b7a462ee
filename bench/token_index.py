"""Benchmark the loader's token index against ``pyarrow.compute.index_in``.

Both answer what the loader asks (:class:`~sianms_cli.nuscenes.token_index.TokenIndex`):
build an index of a table's tokens and report its first duplicate, then give the row of every
query token, -1 for a token that is not there. Random 32-hex tokens, three cases, each timed
for both in the same run (best of ``--repeat``), with the ratio arrow / ours:

- ``trainval``: 1.2 M tokens (sample_annotation), 2.6 M queries, 10 % of them misses, looked up
  in one call;
- ``mini``: 18,538 tokens, 40,000 queries, one call (v1.0-mini's sample_annotation);
- ``in pieces``: 2.6 M tokens (ego_pose), 2.6 M queries in 40 calls of 65,000 (the loader
  resolves sample_data's ego_pose_token one 32 MB piece of sample_data.json at a time).

Every answer of pyarrow is checked equal to ours.

    python bench/token_index.py
    python bench/token_index.py --repeat 1 --cases mini trainval
"""

from __future__ import annotations

import argparse
import time
from typing import Callable

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from sianms_cli.nuscenes.token_index import TokenIndex

CASES = {  # name: (tokens, queries, lookup calls)
    "trainval": (1_200_000, 2_600_000, 1),
    "mini": (18_538, 40_000, 1),
    "in pieces": (2_600_000, 2_600_000, 40),
}
MISS_FRACTION = 0.1


class ArrowTokenIndex:
    """The candidate: ``pyarrow.compute.index_in`` behind the TokenIndex interface.

    The tokens are converted to Arrow once; index_in hashes the whole set again on every call.
    """

    def __init__(self, tokens: np.ndarray) -> None:
        self._tokens = pa.array(tokens)

    def first_duplicate(self) -> tuple[int, int] | None:
        # index_in gives the first row holding each token: a row that is not its own is a repeat.
        first = pc.index_in(self._tokens, value_set=self._tokens).to_numpy()
        later = np.flatnonzero(first != np.arange(len(first)))
        if len(later) == 0:
            return None
        return int(first[later[0]]), int(later[0])

    def lookup(self, queries: np.ndarray) -> np.ndarray:
        rows = pc.index_in(pa.array(queries.reshape(-1)), value_set=self._tokens)
        return rows.fill_null(-1).to_numpy().astype(np.int64).reshape(queries.shape)


def hex_tokens(rng: np.random.Generator, count: int) -> np.ndarray:
    """(count,) <U32 random lower-case hex tokens, like nuScenes tokens."""
    digits = np.frombuffer(b"0123456789abcdef", np.uint8).astype(np.uint32)
    return np.ascontiguousarray(digits[rng.integers(0, 16, (count, 32))]).view("<U32").reshape(count)


def workload(tokens: int, queries: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(tokens, queries): queries drawn from the tokens, MISS_FRACTION of them absent."""
    rng = np.random.default_rng(seed)
    table = hex_tokens(rng, tokens)
    asked = table[rng.integers(0, tokens, queries)]
    misses = rng.random(queries) < MISS_FRACTION
    asked[misses] = hex_tokens(rng, int(misses.sum()))
    return table, asked


def run(index_class: Callable, tokens: np.ndarray, pieces: list[np.ndarray]):
    """(seconds to build + check duplicates, seconds for every lookup, duplicate, rows)."""
    start = time.perf_counter()
    index = index_class(tokens)
    duplicate = index.first_duplicate()
    built = time.perf_counter()
    rows = [index.lookup(piece) for piece in pieces]
    return built - start, time.perf_counter() - built, duplicate, np.concatenate(rows)


def measure(name: str, repeat: int, seed: int) -> None:
    count, queries, calls = CASES[name]
    tokens, asked = workload(count, queries, seed)
    pieces = np.array_split(asked, calls)
    best = {}
    for _ in range(repeat):
        for label, index_class in (("ours", TokenIndex), ("arrow", ArrowTokenIndex)):
            result = run(index_class, tokens, pieces)
            if label not in best or sum(result[:2]) < sum(best[label][:2]):
                best[label] = result
    ours, arrow = best["ours"], best["arrow"]
    if ours[2] != arrow[2] or not np.array_equal(ours[3], arrow[3]):
        raise SystemExit(f"{name}: pyarrow and TokenIndex disagree")
    print(f"{name}: {count:,} tokens, {queries:,} queries ({MISS_FRACTION:.0%} misses) in {calls} call(s)")
    for label, (build, lookup, _, _) in (("TokenIndex", ours), ("pyarrow index_in", arrow)):
        print(f"  {label:17s} build {build:7.3f} s  lookup {lookup:7.3f} s  total {build + lookup:7.3f} s")
    print(f"  arrow / ours = {(arrow[0] + arrow[1]) / (ours[0] + ours[1]):.2f}x (total time)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeat", type=int, default=3, help="runs per case; the best time counts")
    parser.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    for name in args.cases:
        measure(name, args.repeat, args.seed)


if __name__ == "__main__":
    main()
