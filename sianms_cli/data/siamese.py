"""The siamese training and validation data: scene-by-scene streaming and the online pairing of paper §IV-B.

Streaming: a cache holds one detections file and one pairs file per scene (the shard), and
every pairing of the paper stays inside one scene, so the reader loads one scene at a time
(only the columns it needs) and memory stays flat in the cache's size.

The online pairing, per epoch (docs/methods.md#online-hard-negatives):

1. each reference instance (a row in ``pairs/``: seen by two contiguous cameras in one sample)
   once, in random order, with a random occurrence in a random direction;
2. the positive: the same instance's detection in the contiguous camera, same sample;
3. the negative candidates: another instance of the scene, drawn among those with a detection
   in the contiguous camera's overlap with the reference camera (``overlap_pairs``), and every
   such detection of it in the scene; the training step back-propagates the highest-loss one
   (:func:`hardest_candidates`). Only where the overlap holds no other instance do the
   candidates come from the whole contiguous camera (counted as ``negative_fallback``); an
   occurrence whose contiguous camera sees no other instance is not drawn, so every
   reference gets one positive and one negative: 50 : 50.

Detections without an instance (false positives) are never candidates.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Iterator

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from sianms_cli.data.cache import (decode_roi_features, read_shard_table, roi_feature_shape, verified_shard,
                                   verified_shards)
from sianms_cli.errors import DataFormatError

DETECTION_COLUMNS = ["detection_id", "scene_token", "sample_token", "camera", "instance_token", "overlap_pairs",
                     "roi_feature"]
PAIR_COLUMNS = ["scene_token", "instance_token", "pair", "reference_detection_id", "positive_detection_id"]


def shard_paths(cache: str | Path) -> list[Path]:
    """The detections files of a cache, in name order (one per scene), checked against its manifest."""
    return verified_shards(cache, "detections")


def cache_feature_shape(cache: str | Path) -> tuple[int, int, int]:
    """(C, PH, PW) of a cache's ROI features (the same in every shard, checked)."""
    shapes = {roi_feature_shape(path) for path in shard_paths(cache)}
    if len(shapes) != 1:
        raise DataFormatError(Path(cache) / "detections", f"shards disagree on the ROI feature shape: {sorted(shapes)}")
    return shapes.pop()


# --------------------------------------------------------------------------- one scene


@dataclass
class Scene:
    """One scene's detections as aligned arrays (row = detection, file order).

    ``instance`` and ``sample`` are integer codes (-1: no instance); ``overlap`` maps each
    pair name "CAM_A|CAM_B" to the boolean mask of the rows in that pair's overlap;
    ``pair_rows`` (M, 2) are the (reference, positive) rows of the scene's pairs rows and
    ``pair_names`` (M,) their pair.
    """

    scene_token: str
    detection_id: np.ndarray
    camera: np.ndarray
    sample: np.ndarray
    instance: np.ndarray
    instance_tokens: list[str]
    overlap: dict[str, np.ndarray]
    features: np.ndarray  # (N, C, PH, PW) float16
    pair_rows: np.ndarray
    pair_names: np.ndarray

    def __len__(self) -> int:
        return len(self.detection_id)


def _codes(column: pa.ChunkedArray) -> tuple[np.ndarray, list]:
    """Integer codes of a string column in order of first appearance (null -> -1), and the values."""
    encoded = pc.dictionary_encode(column.combine_chunks())
    codes = pc.fill_null(encoded.indices, -1).to_numpy(zero_copy_only=False).astype(np.int64)
    return codes, encoded.dictionary.to_pylist()


def _overlap_masks(column: pa.ChunkedArray, names: list[str]) -> dict[str, np.ndarray]:
    """{pair name: boolean mask of the rows whose ``overlap_pairs`` list holds it}."""
    lists = column.combine_chunks()
    flat = pc.list_flatten(lists).to_numpy(zero_copy_only=False)
    parent = pc.list_parent_indices(lists).to_numpy()
    masks = {}
    for name in names:
        mask = np.zeros(len(lists), dtype=bool)
        mask[parent[flat == name]] = True
        masks[name] = mask
    return masks


def _scene_from_tables(detections: pa.Table, pairs: pa.Table, shape: tuple[int, ...], path: Path) -> Scene:
    """Build a :class:`Scene` from one scene's detections and pairs tables, column-wise."""
    ids = detections.column("detection_id").combine_chunks()
    instance, tokens = _codes(detections.column("instance_token"))
    sample, _ = _codes(detections.column("sample_token"))
    if pairs.column("pair").null_count:
        raise DataFormatError(path.parent.parent / "pairs" / path.name, "a pairs row without its camera pair",
                              field="pair")
    pair_names = pairs.column("pair").to_numpy(zero_copy_only=False).astype(object)
    names = sorted(set(pc.unique(pc.list_flatten(detections.column("overlap_pairs"))).to_pylist()) | set(pair_names))
    fields = ("reference_detection_id", "positive_detection_id")
    rows = [pc.index_in(pairs.column(field), value_set=ids) for field in fields]
    for field, column in zip(fields, rows):
        if column.null_count:
            raise DataFormatError(path.parent.parent / "pairs" / path.name,
                                  "a pairs row names a detection the scene's detections lack", field=field)
    return Scene(scene_token=detections.column("scene_token")[0].as_py() if len(ids) else "",
                 detection_id=ids.to_numpy(zero_copy_only=False).astype(object),
                 camera=detections.column("camera").to_numpy().astype(object),
                 sample=sample, instance=instance, instance_tokens=tokens,
                 overlap=_overlap_masks(detections.column("overlap_pairs"), names),
                 features=decode_roi_features(detections.column("roi_feature"), shape, path),
                 pair_rows=np.stack([column.to_numpy(zero_copy_only=False) for column in rows], axis=1).astype(np.int64)
                 .reshape(-1, 2), pair_names=pair_names)


def iter_scenes(cache: str | Path, order: np.ndarray | None = None) -> Iterator[Scene]:
    """The cache's scenes one at a time (shard order, or ``order`` of the shard indices).

    Reads only the columns the siamese net needs; a shard holding several scenes (a cache
    written by another tool) is split by ``scene_token``.
    """
    paths = shard_paths(cache)
    shape = cache_feature_shape(cache)
    for index in (range(len(paths)) if order is None else order):
        path = paths[index]
        detections = read_shard_table(path, columns=DETECTION_COLUMNS)
        pairs = read_shard_table(verified_shard(cache, "pairs", path.stem), columns=PAIR_COLUMNS)
        scene_tokens = detections.column("scene_token").to_pylist()
        for token in dict.fromkeys(scene_tokens):
            if len(set(scene_tokens)) == 1:
                yield _scene_from_tables(detections, pairs, shape, path)
            else:
                keep = np.array([t == token for t in scene_tokens])
                keep_pairs = np.array([t == token for t in pairs.column("scene_token").to_pylist()], dtype=bool)
                yield _scene_from_tables(detections.filter(keep), pairs.filter(keep_pairs), shape, path)


def feature_statistics(cache: str | Path) -> tuple[np.ndarray, np.ndarray, int]:
    """Per-channel mean and standard deviation of a cache's ROI features, and the detections counted.

    Over every detection (labelled or not: the encoder sees all of them at inference) and
    every ROI cell, streamed scene by scene and summed in float64, so the result does not
    depend on the scene order. Returns (C,) float64 mean, (C,) float64 std (population), N.
    """
    shape = cache_feature_shape(cache)
    total = np.zeros(shape[0])
    squares = np.zeros(shape[0])
    count = 0
    for path in shard_paths(cache):
        column = read_shard_table(path, columns=["roi_feature"]).column("roi_feature")
        features = decode_roi_features(column, shape, path).astype(np.float64)
        total += features.sum(axis=(0, 2, 3))
        squares += np.square(features).sum(axis=(0, 2, 3))
        count += len(features)
    if count == 0:
        raise DataFormatError(Path(cache) / "detections", "no detections: nothing to train on")
    cells = count * shape[1] * shape[2]
    mean = total / cells
    return mean, np.sqrt(np.maximum(squares / cells - mean ** 2, 0.0)), count


# --------------------------------------------------------------------------- the pairing


@dataclass
class Occurrence:
    """One directed occurrence of a reference instance and the negatives it may draw.

    ``negatives`` maps each other instance (code) to its candidate rows; ``fallback`` says
    they come from the whole contiguous camera (the overlap held no other instance).
    """

    reference: int
    positive: int
    negatives: dict[int, np.ndarray]
    fallback: bool


def negative_candidates(scene: Scene, pair: str, camera: str, instance: int) -> tuple[dict[int, np.ndarray], bool]:
    """{other instance: its candidate rows} for a reference of ``instance`` whose contiguous camera is ``camera``.

    Candidates: detections of another instance of the scene in ``camera`` inside ``pair``'s
    overlap; when there are none, every detection of another instance in ``camera`` (the
    fallback, flagged True). Returns ({}, False) when the camera sees no other instance.
    """
    other = (scene.camera == camera) & (scene.instance >= 0) & (scene.instance != instance)
    in_overlap = other & scene.overlap.get(pair, np.zeros(len(scene), dtype=bool))
    fallback = not in_overlap.any()
    rows = np.flatnonzero(other if fallback else in_overlap)
    if len(rows) == 0:
        return {}, False
    groups = {int(code): rows[scene.instance[rows] == code] for code in np.unique(scene.instance[rows])}
    return groups, fallback


def scene_occurrences(scene: Scene) -> dict[int, list[Occurrence]]:
    """{reference instance: its directed occurrences that have at least one negative}."""
    found: dict[int, list[Occurrence]] = {}
    for (row_a, row_b), pair in zip(scene.pair_rows, scene.pair_names):
        for reference, positive in ((row_a, row_b), (row_b, row_a)):
            instance = int(scene.instance[reference])
            negatives, fallback = negative_candidates(scene, pair, scene.camera[positive], instance)
            if negatives:
                found.setdefault(instance, []).append(Occurrence(int(reference), int(positive), negatives, fallback))
    return found


@dataclass
class PairingBatch:
    """References, positives and the ragged negative candidates of K items.

    ``candidate_item`` (S,) says which item each candidate row belongs to (sorted);
    ``*_id`` and ``*_instance`` (tokens) are there for checks and tests.
    """

    reference: np.ndarray  # (K, C, PH, PW) float16
    positive: np.ndarray  # (K, C, PH, PW)
    candidates: np.ndarray  # (S, C, PH, PW)
    candidate_item: np.ndarray  # (S,) int64
    fallback: np.ndarray  # (K,) bool
    reference_id: np.ndarray
    positive_id: np.ndarray
    candidate_id: np.ndarray
    reference_instance: np.ndarray
    candidate_instance: np.ndarray
    scene_token: np.ndarray  # (K,)

    def __len__(self) -> int:
        return len(self.reference)

    @staticmethod
    def empty(feature_shape: tuple[int, int, int]) -> PairingBatch:
        """A batch of no items, for ROI features of ``feature_shape`` (C, PH, PW)."""
        features = np.zeros((0, *feature_shape), dtype=np.float16)
        rows, names = np.zeros(0, dtype=np.int64), np.zeros(0, dtype=object)
        return PairingBatch(features, features, features, rows, np.zeros(0, dtype=bool), names, names, names, names,
                            names, names)

    def take(self, start: int, stop: int) -> PairingBatch:
        """Items [start, stop) with their candidates."""
        lo, hi = np.searchsorted(self.candidate_item, [start, stop])
        return PairingBatch(
            self.reference[start:stop], self.positive[start:stop], self.candidates[lo:hi],
            self.candidate_item[lo:hi] - start, self.fallback[start:stop], self.reference_id[start:stop],
            self.positive_id[start:stop], self.candidate_id[lo:hi], self.reference_instance[start:stop],
            self.candidate_instance[lo:hi], self.scene_token[start:stop])

    @staticmethod
    def concatenate(parts: list[PairingBatch]) -> PairingBatch:
        """The items of ``parts`` in order, candidates renumbered."""
        if len(parts) == 1:
            return parts[0]
        offsets = np.cumsum([0] + [len(part) for part in parts[:-1]])
        columns = {field.name: np.concatenate([getattr(p, field.name) for p in parts])
                   for field in fields(PairingBatch) if field.name != "candidate_item"}
        candidate_item = np.concatenate([p.candidate_item + offset for p, offset in zip(parts, offsets)])
        return PairingBatch(candidate_item=candidate_item, **columns)


def draw_scene_items(scene: Scene, rng: np.random.Generator) -> PairingBatch | None:
    """One epoch's items of a scene: each reference instance once, in random order (see module doc)."""
    occurrences = scene_occurrences(scene)
    if not occurrences:
        return None
    instances = np.array(sorted(occurrences))[rng.permutation(len(occurrences))]
    chosen = []
    for instance in instances:
        options = occurrences[int(instance)]
        occurrence = options[rng.integers(len(options))]
        negatives = sorted(occurrence.negatives)
        rows = occurrence.negatives[negatives[rng.integers(len(negatives))]]
        chosen.append((occurrence, rows))
    reference = np.array([o.reference for o, _ in chosen])
    positive = np.array([o.positive for o, _ in chosen])
    candidates = np.concatenate([rows for _, rows in chosen])
    item = np.repeat(np.arange(len(chosen)), [len(rows) for _, rows in chosen])
    tokens = np.array(scene.instance_tokens + [None], dtype=object)
    return PairingBatch(
        scene.features[reference], scene.features[positive], scene.features[candidates], item,
        np.array([o.fallback for o, _ in chosen]), scene.detection_id[reference], scene.detection_id[positive],
        scene.detection_id[candidates], tokens[scene.instance[reference]], tokens[scene.instance[candidates]],
        np.full(len(chosen), scene.scene_token, dtype=object))


def epoch_batches(cache: str | Path, batch_size: int, rng: np.random.Generator,
                  shards: np.ndarray | None = None) -> Iterator[PairingBatch]:
    """The epoch's batches of ``batch_size`` reference items (the last may be smaller).

    Scenes are visited in a random order (or the shard indices ``shards``, in order: a
    stream's, :mod:`sianms_cli.data.streams`), one loaded at a time; a batch may join the end
    of one scene with the start of the next.
    """
    pending: list[PairingBatch] = []
    count = 0
    for scene in iter_scenes(cache, order=rng.permutation(len(shard_paths(cache))) if shards is None else shards):
        items = draw_scene_items(scene, rng)
        if items is None:
            continue
        pending.append(items)
        count += len(items)
        while count >= batch_size:
            joined = PairingBatch.concatenate(pending)
            yield joined.take(0, batch_size)
            rest = joined.take(batch_size, len(joined))
            pending, count = ([rest] if len(rest) else []), len(rest)
    if count:
        yield PairingBatch.concatenate(pending)


def hardest_candidates(distances: np.ndarray, candidate_item: np.ndarray, items: int) -> np.ndarray:
    """Index of each item's highest-loss candidate, (items,) int64.

    The negative term ½ max(β − d, 0)² falls as the distance d grows, so the highest-loss
    candidate is the nearest one; choosing by distance also breaks the ties of candidates
    already beyond β (all zero loss) towards the hardest, and exact ties towards the first.
    ``distances`` (S,) from each candidate to its item's reference; ``candidate_item`` (S,)
    sorted item indices; every item has at least one candidate.
    """
    order = np.lexsort((np.arange(len(distances)), np.asarray(distances, dtype=np.float64), candidate_item))
    return order[np.searchsorted(candidate_item[order], np.arange(items))]
