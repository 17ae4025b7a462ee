"""Token -> row lookup for the tables of a nuScenes dataroot.

Every token of a table gets a 64-bit key (a fixed linear hash of its characters); the keys
are sorted once, and a batch of query tokens is looked up with ``np.searchsorted``, every hit
confirmed against the token itself. If two tokens of a table share a key, the index sorts the
token strings instead, which is slower but exact.

Why not ``pyarrow.compute.index_in``: it hashes the whole table again on every call, and the
loader looks up each piece of a large table file separately (the ego poses of every 32 MB of
sample_data.json: about 40 calls against 2.6 M ego_pose tokens on v1.0-trainval). There this
index is much faster; on one large lookup the two take the same time (``bench/token_index.py``
measures both).
"""

from __future__ import annotations

import numpy as np

# Queries looked up at a time: a gathered candidate token takes 128 bytes (32 characters), so
# a block's temporaries stay a few MB instead of 330 MB for 2.6 M queries; fresh pages for
# those cost more than the lookup itself.
_LOOKUP_BLOCK = 1 << 16


def _hash_multipliers(count: int) -> np.ndarray:
    """``count`` fixed odd 64-bit multipliers (splitmix64 of 1, 2, ...), one per word."""
    with np.errstate(over="ignore"):
        z = np.arange(1, count + 1, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    return z | np.uint64(1)


def _token_keys(tokens: np.ndarray) -> np.ndarray:
    """A uint64 key per token of a numpy unicode array, independent of the array's width.

    The key is a sum of the token's 64-bit words (two UCS-4 characters each) times fixed
    multipliers; the zero padding of a wider array adds nothing, so the same token gets the
    same key in arrays of any width.
    """
    chars = tokens.dtype.itemsize // 4
    if chars % 2:
        tokens = tokens.astype(f"<U{chars + 1}")
        chars += 1
    words = np.ascontiguousarray(tokens).view(np.uint64).reshape(len(tokens), chars // 2)
    keys = np.zeros(len(tokens), dtype=np.uint64)
    with np.errstate(over="ignore"):
        for column, multiplier in enumerate(_hash_multipliers(words.shape[1])):
            keys += words[:, column] * multiplier
    return keys


class TokenIndex:
    """Token -> row of one table's tokens (a numpy unicode array, in row order).

    Attributes:
        by_string: two tokens share a 64-bit key (a collision or a duplicate token), so the
            index sorts the strings themselves.
    """

    def __init__(self, tokens: np.ndarray) -> None:
        self._tokens = tokens
        keys = _token_keys(tokens) if len(tokens) else np.zeros(0, dtype=np.uint64)
        order = np.argsort(keys, kind="stable")
        sorted_keys = keys[order]
        self.by_string = bool((sorted_keys[1:] == sorted_keys[:-1]).any())
        if self.by_string:
            order = np.argsort(tokens, kind="stable")
            sorted_keys = tokens[order]
        self._order = order
        self._sorted_keys = sorted_keys

    def __len__(self) -> int:
        return len(self._tokens)

    def first_duplicate(self) -> tuple[int, int] | None:
        """Rows (earlier, later) of the first token (in row order) seen twice, or None."""
        if not self.by_string:
            return None  # distinct keys: distinct tokens
        same = np.flatnonzero(self._sorted_keys[1:] == self._sorted_keys[:-1])
        if len(same) == 0:
            return None
        later = self._order[same + 1]
        pick = int(np.argmin(later))
        return int(self._order[same[pick]]), int(later[pick])

    def lookup(self, queries: np.ndarray) -> np.ndarray:
        """int64 row of each query token (a numpy unicode array of any shape), -1 if absent."""
        flat = queries.reshape(-1)
        rows = np.full(len(flat), -1, dtype=np.int64)
        if len(self._tokens):
            for start in range(0, len(flat), _LOOKUP_BLOCK):
                rows[start:start + _LOOKUP_BLOCK] = self._lookup_block(flat[start:start + _LOOKUP_BLOCK])
        return rows.reshape(queries.shape)

    def _lookup_block(self, flat: np.ndarray) -> np.ndarray:
        keys = flat if self.by_string else _token_keys(flat)
        # Sorted queries make searchsorted walk the sorted keys in order (cache-friendly).
        query_order = np.argsort(keys, kind="stable")
        positions = np.empty(len(flat), dtype=np.int64)
        positions[query_order] = np.searchsorted(self._sorted_keys, keys[query_order])
        candidates = self._order[np.minimum(positions, len(self._order) - 1)]
        found = (positions < len(self._order)) & (self._tokens[candidates] == flat)
        return np.where(found, candidates, -1)
