"""The index the online hard-negative sampler needs (paper §IV-B).

For a reference instance in camera pair (A, B) of a scene, the sampler picks another
instance of the same scene and runs *all its occurrences in the overlap area* of that pair.
:func:`build_pair_index` groups the detections of ``detections/`` by (scene, camera pair,
instance), where a detection belongs to pair P when its associated box centre lies in P's
overlap region (THE overlap rule, column ``overlap_pairs``).
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

from sianms_cli.data.cache import read_shard_table, verified_shards

PairIndex = dict[tuple[str, str], dict[str, list[str]]]


def build_pair_index(cache: str | Path) -> PairIndex:
    """{(scene_token, pair): {instance_token: [detection_id, ...]}} from a prepared cache.

    Reads only four columns, one shard file at a time. Detection ids are in file order.
    """
    index: PairIndex = defaultdict(lambda: defaultdict(list))
    for path in verified_shards(cache, "detections"):
        table = read_shard_table(path, columns=["scene_token", "instance_token", "detection_id", "overlap_pairs"])
        for scene, instance, detection, pairs in zip(*(table.column(i).to_pylist() for i in range(4))):
            if instance is None:
                continue
            for pair in pairs or ():
                index[(scene, pair)][instance].append(detection)
    return {key: dict(value) for key, value in index.items()}
