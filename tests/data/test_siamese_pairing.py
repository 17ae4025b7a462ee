"""The online pairing of §IV-B: candidates, the hard-negative choice, 50 : 50, streaming scene by scene."""

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch
from cache_records import record_again

from sianms_cli.data import siamese as data
from sianms_cli.data.schemas import cache_schemas
from sianms_cli.data.siamese import Scene, epoch_batches, hardest_candidates, negative_candidates, scene_occurrences
from sianms_cli.errors import DataFormatError
from sianms_cli.models.losses import negative_terms

A, B, C = "CAM_FRONT_LEFT", "CAM_FRONT", "CAM_BACK"
PAIR = f"{A}|{B}"
SHAPE = (2, 1, 1)

# row: camera, sample, instance (None: unmatched), in the A|B overlap
ROWS = [
    (A, 0, 0, True),     # 0 reference of instance 0
    (B, 0, 0, True),     # 1 its positive
    (B, 0, 1, True),     # 2 candidate: instance 1 in B's overlap
    (B, 1, 1, True),     # 3 candidate: instance 1 in another sample of the scene
    (B, 1, 2, False),    # 4 instance 2 in B but outside the overlap
    (A, 0, 1, True),     # 5 instance 1 in A (the candidate of the other direction)
    (B, 0, None, True),  # 6 unmatched: never a candidate
    (C, 0, 1, False),    # 7 another camera
]


def make_scene(rows=ROWS, pairs=((0, 1),), token="scene-a") -> Scene:
    camera, sample, instance, overlap = zip(*rows)
    return Scene(
        scene_token=token, detection_id=np.array([f"{token}_{i}" for i in range(len(rows))], dtype=object),
        camera=np.array(camera, dtype=object), sample=np.array(sample),
        instance=np.array([-1 if i is None else i for i in instance]),
        instance_tokens=[f"{token}-inst{i}" for i in range(3)], overlap={PAIR: np.array(overlap)},
        features=np.arange(len(rows) * 2, dtype=np.float16).reshape(len(rows), *SHAPE),
        pair_rows=np.array(pairs).reshape(-1, 2), pair_names=np.array([PAIR] * len(pairs), dtype=object))


def test_candidates_come_from_the_contiguous_cameras_overlap():
    scene = make_scene()
    negatives, fallback = negative_candidates(scene, PAIR, B, instance=0)
    assert not fallback
    # not 4 (outside the overlap), 6 (no instance), 7 (camera C)
    assert {k: v.tolist() for k, v in negatives.items()} == {1: [2, 3]}
    negatives, fallback = negative_candidates(scene, PAIR, A, instance=0)
    assert {k: v.tolist() for k, v in negatives.items()} == {1: [5]} and not fallback


def test_fallback_to_the_whole_camera_only_when_the_overlap_holds_no_other_instance():
    rows = [(c, s, i, o and i == 0) for c, s, i, o in ROWS]  # only instance 0 left in the overlap
    negatives, fallback = negative_candidates(make_scene(rows), PAIR, B, instance=0)
    assert fallback
    assert {k: v.tolist() for k, v in negatives.items()} == {1: [2, 3], 2: [4]}


def test_an_occurrence_without_any_negative_is_not_drawn():
    rows = [(A, 0, 0, True), (B, 0, 0, True), (A, 0, 1, True)]  # B sees no other instance
    occurrences = scene_occurrences(make_scene(rows))
    assert [(o.reference, o.positive) for o in occurrences[0]] == [(1, 0)]  # only the direction B -> A


def test_hardest_candidate_is_the_highest_loss_one():
    rng = np.random.default_rng(0)
    items = np.sort(rng.integers(0, 6, size=40))
    items[:6] = np.arange(6)  # every item has a candidate
    items = np.sort(items)
    distances = rng.uniform(0, 5, size=40)
    distances[7] = distances[8] = 0.1  # an exact tie inside an item
    chosen = hardest_candidates(distances, items, 6)
    losses = negative_terms(torch.tensor(distances)).numpy()
    for item in range(6):
        mine = np.flatnonzero(items == item)
        assert items[chosen[item]] == item
        assert losses[chosen[item]] == losses[mine].max()
        assert chosen[item] == mine[np.argmin(distances[mine])]  # nearest; the first on ties


def test_all_candidates_beyond_beta_picks_the_nearest():
    assert hardest_candidates(np.array([7.0, 4.0, 9.0]), np.array([0, 0, 0]), 1).tolist() == [1]


def test_scene_items_are_fifty_fifty_and_never_the_same_instance():
    scene = make_scene(pairs=((0, 1), (5, 2)))  # instance 0 in A|B, instance 1 in A|B
    batch = data.draw_scene_items(scene, np.random.default_rng(1))
    assert len(batch) == 2 and len(batch.positive) == 2  # one positive and one negative per reference
    for item in range(len(batch)):
        mine = batch.candidate_item == item
        assert mine.any()
        assert not (batch.candidate_instance[mine] == batch.reference_instance[item]).any()


# --------------------------------------------------------------------------- a handmade cache


def write_cache(root: Path, scenes: dict[str, list], pairs: dict[str, list]) -> Path:
    """A cache of one shard per scene with just enough columns filled; rows as in ROWS."""
    schemas = cache_schemas(SHAPE, "tiny")
    for name, rows in scenes.items():
        count = len(rows)
        detections = {field.name: [None] * count for field in schemas["detections"]}
        detections |= {
            "detection_id": [f"{name}_{i}" for i in range(count)], "scene_token": [name] * count,
            "sample_token": [f"{name}-s{s}" for _, s, _, _ in rows], "camera": [c for c, _, _, _ in rows],
            "instance_token": [None if i is None else f"{name}-inst{i}" for _, _, i, _ in rows],
            "overlap_pairs": [[PAIR] if o else [] for _, _, _, o in rows],
            "roi_feature": [np.full(SHAPE, i, dtype="<f2").tobytes() for i in range(count)],
        }
        (root / "detections").mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.table(detections, schema=schemas["detections"]), root / "detections" / f"{name}.parquet")
        table = {field.name: [None] * len(pairs[name]) for field in schemas["pairs"]}
        table |= {"scene_token": [name] * len(pairs[name]), "pair": [PAIR] * len(pairs[name]),
                  "instance_token": [f"{name}-inst{rows[a][2]}" for a, _ in pairs[name]],
                  "reference_detection_id": [f"{name}_{a}" for a, _ in pairs[name]],
                  "positive_detection_id": [f"{name}_{b}" for _, b in pairs[name]]}
        (root / "pairs").mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.table(table, schema=schemas["pairs"]), root / "pairs" / f"{name}.parquet")
    return record_again(root)


@pytest.fixture
def two_scene_cache(tmp_path):
    return write_cache(tmp_path / "cache", {"scene-a": ROWS, "scene-b": ROWS},
                       {"scene-a": [(0, 1), (5, 2)], "scene-b": [(0, 1), (5, 2)]})


def test_epoch_batches_keep_every_candidate_in_the_reference_scene(two_scene_cache):
    batches = list(epoch_batches(two_scene_cache, 3, np.random.default_rng(0)))
    assert [len(b) for b in batches] == [3, 1]  # 4 reference instances, a batch across the scene boundary
    for batch in batches:
        for item in range(len(batch)):
            mine = batch.candidate_item == item
            scene = batch.scene_token[item]
            assert all(c.startswith(scene + "_") for c in batch.candidate_id[mine])
            positive_camera = ROWS[int(batch.positive_id[item].rsplit("_", 1)[1])][0]
            for candidate in batch.candidate_id[mine]:
                camera, _, _, in_overlap = ROWS[int(candidate.rsplit("_", 1)[1])]
                assert camera == positive_camera and in_overlap
            assert not (batch.candidate_instance[mine] == batch.reference_instance[item]).any()
        # the features travel with their rows: detection i holds the value i
        assert [int(v) for v in batch.reference[:, 0, 0, 0]] == [int(d.rsplit("_", 1)[1]) for d in batch.reference_id]


def test_epoch_batches_are_seeded(two_scene_cache):
    def ids(seed):
        return [list(b.reference_id) + list(b.candidate_id)
                for b in epoch_batches(two_scene_cache, 2, np.random.default_rng(seed))]

    assert ids(5) == ids(5)
    assert any(ids(seed) != ids(5) for seed in range(6, 12))


def test_scenes_are_read_one_at_a_time_with_only_the_needed_columns(two_scene_cache, monkeypatch):
    reads = []
    real = data.read_shard_table
    def read_table(path, columns=None):
        reads.append((Path(path).parent.name, columns))
        return real(path, columns=columns)

    monkeypatch.setattr(data, "read_shard_table", read_table)
    iterator = data.iter_scenes(two_scene_cache)
    next(iterator)
    assert [folder for folder, _ in reads] == ["detections", "pairs"]  # the second scene is not read yet
    assert reads[0][1] == data.DETECTION_COLUMNS and "frustums" not in str(reads)


def test_a_cache_without_detections_is_a_clear_error(tmp_path):
    with pytest.raises(DataFormatError, match="not a `sianms prepare` cache"):
        list(epoch_batches(tmp_path, 2, np.random.default_rng(0)))


def test_a_pairs_row_naming_an_unknown_detection_is_a_clear_error(tmp_path):
    cache = write_cache(tmp_path / "cache", {"scene-a": ROWS}, {"scene-a": [(0, 1)]})
    table = pq.read_table(cache / "pairs" / "scene-a.parquet")
    ids = pa.array(["scene-a_99"], type=pa.string())
    pq.write_table(table.set_column(table.schema.get_field_index("positive_detection_id"), "positive_detection_id",
                                    ids), cache / "pairs" / "scene-a.parquet")
    record_again(cache)
    with pytest.raises(DataFormatError,
                       match="pairs/scene-a.parquet: field 'positive_detection_id': a pairs row names"):
        list(data.iter_scenes(cache))


def test_feature_statistics_against_all_features_at_once(tmp_path):
    cache = write_cache(tmp_path / "cache", {"scene-a": ROWS, "scene-b": ROWS[:3]},
                        {"scene-a": [(0, 1)], "scene-b": [(0, 1)]})
    mean, std, count = data.feature_statistics(cache)
    everything = np.concatenate([scene.features for scene in data.iter_scenes(cache)]).astype(np.float64)
    assert count == len(ROWS) + 3 and mean.shape == std.shape == (SHAPE[0],)
    np.testing.assert_allclose(mean, everything.mean(axis=(0, 2, 3)), rtol=1e-12)
    np.testing.assert_allclose(std, everything.std(axis=(0, 2, 3)), rtol=1e-12)
