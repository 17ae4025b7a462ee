"""Streams: each reads only the shards dealt to it, and together they read every training item once."""

import numpy as np
import pyarrow.parquet as pq
import pytest

from sianms_cli.data.frustum_dataset import FrustumSelection, frustum_shards, iterate_batches
from sianms_cli.data.siamese import epoch_batches, shard_paths
from sianms_cli.data.streams import check_streams, deal_shards, rank_epoch_streams, rank_streams, stream_batch_size, \
    stream_steps
from sianms_cli.errors import SianmsError

EVERY_FRUSTUM = FrustumSelection(num_points=8, min_box_height=0)


def test_dealing_gives_each_shard_to_the_lightest_stream_and_one_stream_the_plain_random_order():
    sizes = [50, 10, 10, 10, 10, 10, 40]
    order = np.random.default_rng(3).permutation(7).tolist()
    dealt = deal_shards(sizes, np.random.default_rng(3), 2)
    loads = [0, 0]
    for shard in order:  # the rule, one shard at a time
        lightest = loads.index(min(loads))
        assert shard in dealt[lightest].tolist()
        loads[lightest] += sizes[shard]
    assert sorted(np.concatenate(dealt).tolist()) == list(range(7))
    assert [[s for s in order if s in part] for part in map(list, dealt)] == [list(part) for part in dealt]
    assert max(loads) - min(loads) <= max(sizes)
    assert deal_shards(sizes, np.random.default_rng(3), 1)[0].tolist() == order
    assert [list(rank_streams(4, rank, 2)) for rank in range(2)] == [[0, 1], [2, 3]]


def test_steps_join_a_processs_streams_in_order_and_an_exhausted_process_takes_part_empty():
    streams = [iter([[1, 2], [3]]), iter([[10, 11], [12, 13], [14]])]
    others = iter([5, 5, 5, 5, 0])  # the other rank's rows at each step
    steps = list(stream_steps(streams, lambda parts: sum(parts, []), [], len, lambda n: [n, next(others)]))
    assert steps == [([1, 2, 10, 11], [4, 5]), ([3, 12, 13], [3, 5]), ([14], [1, 5]), ([], [0, 5])]


@pytest.mark.parametrize("streams, world, batch, message", [
    (0, 1, 8, "--streams must be at least 1, got 0"),
    (3, 2, 8, "--streams 3 is not a multiple of the 2 processes"),
    (4, 1, 7, "--batch-size 7 is too small for 4 streams"),
])
def test_streams_that_cannot_work_are_refused(streams, world, batch, message):
    with pytest.raises(SianmsError, match=message):
        check_streams(streams, world, batch, smallest=2)


def _frustum_ids(cache, shards):
    return {i for path in (frustum_shards(cache)[s] for s in shards)
            for i in pq.read_table(path, columns=["detection_id"])["detection_id"].to_pylist()}


def test_frustum_streams_read_only_their_shards_and_all_of_them_together(two_shard_cache):
    train = two_shard_cache
    dealt = deal_shards([1] * len(frustum_shards(train)), np.random.default_rng(0), 2)
    seen = []
    for stream, shards in enumerate(dealt):
        batches = iterate_batches(train, EVERY_FRUSTUM, 1000, np.random.default_rng(stream), True, shards=shards)
        ids = [i for batch in batches for i in batch["detection_id"]]
        assert ids and set(ids) <= _frustum_ids(train, shards)
        seen += ids
    every = [i for batch in iterate_batches(train, EVERY_FRUSTUM, 4, np.random.default_rng(0), False)
             for i in batch["detection_id"]]
    assert sorted(seen) == sorted(every)


def test_siamese_streams_pair_only_their_scenes(two_shard_cache):
    train = two_shard_cache
    dealt = deal_shards([1] * len(shard_paths(train)), np.random.default_rng(0), 2)
    for stream, shards in enumerate(dealt):
        scenes = {token for s in shards
                  for token in pq.read_table(shard_paths(train)[s], columns=["scene_token"])["scene_token"].to_pylist()}
        batches = list(epoch_batches(train, 3, np.random.default_rng(stream), shards=shards))
        assert batches and {token for batch in batches for token in batch.scene_token} <= scenes


def test_a_streams_batch_size_is_its_share_of_the_global_batch():
    assert [stream_batch_size(7, s, 3) for s in range(3)] == [2, 2, 3]
    assert stream_batch_size(8, 0, 1) == 8


def test_a_rank_runs_its_streams_with_stream_0_continuing_the_epochs_generator(two_shard_cache):
    paths = shard_paths(two_shard_cache)
    epoch = np.random.default_rng(5)
    [only] = rank_epoch_streams(paths, epoch, lambda s: pytest.fail("one stream needs no other generator"), 8, 1, 0, 1)
    assert only.rng is epoch and only.batch_size == 8
    assert only.shards.tolist() == np.random.default_rng(5).permutation(len(paths)).tolist()
    other = np.random.default_rng(9)
    [second] = rank_epoch_streams(paths, np.random.default_rng(5), lambda s: other if s == 1 else None, 7, 2, 1, 2)
    assert second.rng is other and second.batch_size == 4 and len(second.shards) == 1
