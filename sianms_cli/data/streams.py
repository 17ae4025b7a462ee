"""Training data read in streams, so that each distributed rank reads only its share of a cache.

An epoch deals the cache's shards, in the epoch's random order, to S streams, each shard to
the stream with the fewest bytes dealt so far (so the streams' bytes differ by at most one
shard's, and the ranks that run them end their epochs close together). Each stream reads only its shards, with its own
random generator, into batches of its share of the global batch (:func:`stream_batch_size`
rows); a step's global batch is the streams' next batches in stream order. A stream that
runs out adds nothing; the epoch ends when every stream has.

Under ``torchrun`` with K ranks (S a multiple of K), rank r runs streams r S/K ... (r+1) S/K - 1
and reads only their shards: the reading is split K ways instead of repeated K times. One
process with S streams forms the same global batches, so it computes what K ranks compute.
S = 1 is the plain reading: every shard by one stream, batches of B.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator, Sequence, TypeVar

import numpy as np

from sianms_cli.errors import SianmsError

Batch = TypeVar("Batch")


def deal_shards(sizes: Sequence[int], rng: np.random.Generator, streams: int) -> list[np.ndarray]:
    """The shard indices of each of ``streams`` streams, in the order each reads them.

    The shards (``sizes``: their bytes) are taken in a random order, each dealt to the
    stream with the fewest bytes so far (the first of equals); one stream reads them all in
    that order.
    """
    order = rng.permutation(len(sizes))
    if streams == 1:
        return [order]
    loads = np.zeros(streams)
    dealt: list[list[int]] = [[] for _ in range(streams)]
    for shard in order:
        stream = int(np.argmin(loads))
        dealt[stream].append(int(shard))
        loads[stream] += sizes[shard]
    return [np.array(shards, dtype=np.int64) for shards in dealt]


def stream_batch_size(batch_size: int, stream: int, streams: int) -> int:
    """Stream ``stream``'s share of a global batch of ``batch_size`` rows (shares differ by <= 1)."""
    return batch_size * (stream + 1) // streams - batch_size * stream // streams


def rank_streams(streams: int, rank: int, world: int) -> range:
    """The streams rank ``rank`` of ``world`` runs (contiguous, so its rows are contiguous in every global batch)."""
    per_rank = streams // world
    return range(rank * per_rank, (rank + 1) * per_rank)


@dataclass(frozen=True, eq=False)
class Stream:
    """One stream's epoch: the shard indices it reads, in order, its generator and its batch size."""

    shards: np.ndarray
    rng: np.random.Generator
    batch_size: int


def rank_epoch_streams(paths: Sequence[Path], rng: np.random.Generator,
                       stream_rng: Callable[[int], np.random.Generator], batch_size: int, streams: int, rank: int,
                       world: int) -> list[Stream]:
    """The streams rank ``rank`` of ``world`` runs this epoch.

    The shard files ``paths`` are dealt by their bytes with the epoch's generator ``rng``,
    which stream 0 then continues (one stream draws exactly what the plain reading draws);
    stream s > 0 draws from ``stream_rng(s)``.
    """
    dealt = deal_shards([path.stat().st_size for path in paths], rng, streams)
    return [Stream(dealt[s], rng if s == 0 else stream_rng(s), stream_batch_size(batch_size, s, streams))
            for s in rank_streams(streams, rank, world)]


def check_stream_count(streams: int | None) -> None:
    """Refuse a ``--streams`` below 1 (None: one per process, decided when the ranks are known)."""
    if streams is not None and streams < 1:
        raise SianmsError(f"--streams must be at least 1, got {streams}")


def check_streams(streams: int, world: int, batch_size: int, smallest: int) -> None:
    """Refuse stream counts that the ranks cannot share or whose batches would be too small.

    ``smallest``: the fewest rows a stream's batch may have (2 where batch norm sees it).
    """
    check_stream_count(streams)
    if streams % world:
        raise SianmsError(f"--streams {streams} is not a multiple of the {world} processes: each runs the same "
                          "number of streams")
    if batch_size < smallest * streams:
        raise SianmsError(f"--batch-size {batch_size} is too small for {streams} streams: each stream's share "
                          f"of a batch needs at least {smallest}")


def stream_steps(batches: Sequence[Iterator[Batch]], concatenate: Callable[[list[Batch]], Batch], empty: Batch,
                 size: Callable[[Batch], int],
                 row_counts: Callable[[int], list[int]]) -> Iterator[tuple[Batch, list[int]]]:
    """The epoch's steps for this process: (its rows of the global batch, every rank's row count).

    ``batches``: this process's streams' batch iterators, in stream order; ``row_counts``
    turns this process's row count into every rank's (one rank: ``[count]``). A process
    whose streams have run out takes part with ``empty`` until no rank has rows left.
    """
    active = list(batches)
    while True:
        parts = [part for part in (next(stream, None) for stream in active) if part is not None]
        mine = concatenate(parts) if parts else empty
        counts = row_counts(size(mine))
        if sum(counts) == 0:
            return
        yield mine, counts
