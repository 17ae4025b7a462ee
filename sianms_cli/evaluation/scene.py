"""One scene of `sianms eval`: 2-D detections and frustums in, every method's 3-D boxes out.

Per sample (the cache's rows of one key frame), with no access to the ground truth except
the oracle's identity and the ``correct`` column kept for scoring
(docs/methods.md#duplicate-handling):

1. **Inputs**: the detector's detections of Frustum PointNets' classes (never filled-in
   ground truth), at least the training's minimum box height, with a frustum point.
2. **Single-camera boxes** (``kind = single``): Frustum PointNets on each cached frustum,
   moved to the global frame (:mod:`.inference`).
3. **siaNMS matches** (``kind = sianms``), per contiguous camera pair in clockwise order
   (:mod:`.matching`); a detection matched in one pair is not a candidate in the next. A
   match whose frustums do not overlap is a row with ``dismissed`` true and no box; every
   other match gets one box from its union frustum (:mod:`.multiview`), scored with the
   higher of its two 2-D scores.
4. **Oracle matches** (``kind = oracle``): the same candidates paired by ground-truth
   instance, then the same dismissal and aggregation.

The result is one Arrow table per scene (:data:`BOXES_SCHEMA`); which boxes each method
reports is decided afterwards (:mod:`.methods`), so NMS settings can be swept without running
a network again. The metadata ``sianms.timings`` holds the seconds per stage (:data:`STAGES`).
"""

from __future__ import annotations

import json
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator
from weakref import WeakKeyDictionary

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from sianms_cli.data.cache import decode_roi_features, read_shard_table, require_finite, roi_feature_shape
from sianms_cli.data.frustum_dataset import require_point_lists
from sianms_cli.geometry.camera_ring import CameraRig
from sianms_cli.geometry.transforms import sensor_to_global
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.sample_rigs import sample_rigs
from sianms_cli.evaluation.inference import FPointNetPredictor, GlobalBoxes, frustum_boxes_to_global
from sianms_cli.evaluation.matching import (
    allowed_pairs,
    assign,
    in_columns,
    oracle_matches,
    overlap_columns,
    pair_distances,
)
from sianms_cli.evaluation.multiview import pair_geometry, pair_union
from sianms_cli.prepare.sample import SceneRecords, lidar_points_global, scene_records

SINGLE, SIANMS, ORACLE = "single", "sianms", "oracle"
STAGES = ("read", "fpointnet_single", "candidates", "embed", "assign", "union_frustums", "fpointnet_union")
DETECTION_COLUMNS = ["detection_id", "sample_token", "sample_data_token", "camera", "x1", "y1", "x2", "y2",
                     "score", "class", "source", "instance_token", "image_width", "image_height"]
NUMERIC_FRUSTUM_COLUMNS = ["rot_angle", "x", "y", "z", "intensity"]
FRUSTUM_COLUMNS = ["detection_id", *NUMERIC_FRUSTUM_COLUMNS]
NUMERIC_DETECTION_COLUMNS = ["x1", "y1", "x2", "y2", "score"]

BOXES_SCHEMA = pa.schema([
    ("scene_token", pa.string()),
    ("sample_token", pa.string()),
    ("kind", pa.string()),  # single | sianms | oracle
    ("detection_a", pa.string()),  # the box's detection (single) or the pair's first
    ("detection_b", pa.string()),  # the pair's second; null for single
    ("camera_a", pa.string()),
    ("camera_b", pa.string()),
    ("class", pa.string()),
    ("score", pa.float32()),
    ("distance", pa.float32()),  # embedding L2 distance of a siaNMS match; null otherwise
    ("dismissed", pa.bool_()),  # a match whose frustums do not overlap (no box)
    ("correct", pa.bool_()),  # a match of one ground-truth instance (scoring only); null for single
    ("num_points", pa.int32()),  # points in the frustum (union for a match)
    # Vectors are variable-size lists, not fixed-size ones: pyarrow before 26 cannot write a null
    # fixed-size list to Parquet (19-24) or read one back (25).
    ("translation", pa.list_(pa.float64())),  # 3 values, global frame; null when dismissed
    ("size", pa.list_(pa.float64())),  # (w, l, h)
    ("yaw", pa.float64()),
    ("wedges", pa.list_(pa.float64())),  # a match's two frustum wedges, global (x, y) x 3 corners each: 12 values
])
VECTOR_WIDTHS = {"translation": 3, "size": 3, "wedges": 12}


@dataclass(frozen=True)
class SceneSettings:
    """What the per-scene stage needs besides the models.

    Attributes:
        matched_classes: classes siaNMS and the oracle match (the paper: cars).
        dis_thr: embedding distance above which a pair is dismissed.
        max_distance: the maximum detection distance (m): radius of the multi-frustum circle
            and depth of the BEV wedges of the overlap test.
        seed: the evaluation's seed (point sampling, masking).
        sweeps, min_depth, max_depth: the cache's LiDAR settings, so union frustums hold the
            points the cache's single frustums would.
    """

    matched_classes: tuple[str, ...]
    dis_thr: float
    max_distance: float
    seed: int
    sweeps: int
    min_depth: float
    max_depth: float


@dataclass(frozen=True, eq=False)
class SampleInputs:
    """The kept detections of one sample (D rows) and their frustums."""

    detection_id: np.ndarray
    camera: np.ndarray
    boxes2d: np.ndarray  # (D, 4)
    score: np.ndarray
    classes: np.ndarray
    instance: np.ndarray  # "" where none (scoring and oracle only)
    points: np.ndarray  # (M, 4) the frustums' x, y, z (frustum frame) and raw intensity, concatenated
    offsets: np.ndarray  # (D + 1,) frustum d is points[offsets[d]:offsets[d + 1]]
    rot_angle: np.ndarray


class SceneEvaluator:
    """The loaded state of the per-scene stage: dataset, Frustum PointNets, siamese encoder."""

    def __init__(self, db: NuScenesDB, predictor: FPointNetPredictor, encoder: Any, settings: SceneSettings) -> None:
        self.db = db
        self.predictor = predictor
        self.encoder = encoder
        self.settings = settings
        # Per rig object, {(a, b): span}. Keyed by the rig itself, not by its index in a scene's
        # rig list: the indices restart at 0 in every scene, and a cache keyed by them handed a
        # later scene the spans of an earlier scene's calibration.
        self._spans: WeakKeyDictionary[CameraRig, dict[tuple[int, int], tuple[float, float] | None]] = (
            WeakKeyDictionary())
        self.seconds: dict[str, float] = {}  # per stage; a stage never timed reads 0

    @contextmanager
    def _timed(self, stage: str) -> Iterator[None]:
        started = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] = self.seconds.get(stage, 0) + time.perf_counter() - started

    def scene(self, detections_path: Path, frustums_path: Path, scene_token: str) -> pa.Table:
        """The boxes table (:data:`BOXES_SCHEMA`) of one cache shard (a scene), its timings in the metadata."""
        self.seconds = {}
        with self._timed("read"):
            detections = read_shard_table(detections_path, columns=DETECTION_COLUMNS)
            require_finite(detections_path, detections, NUMERIC_DETECTION_COLUMNS)
            frustum_table = read_shard_table(frustums_path, columns=FRUSTUM_COLUMNS)
            require_finite(frustums_path, frustum_table, NUMERIC_FRUSTUM_COLUMNS)
            require_point_lists(frustums_path, frustum_table)
            frustums = _frustum_points(frustum_table, detections["detection_id"])
            records = scene_records(self.db, scene_token, self.settings.sweeps)
        samples = detections["sample_token"].to_numpy(zero_copy_only=False).astype(str)
        rigs, rig_of = sample_rigs(self.db, list(records.sample_tokens))
        tables = []
        for position, sample_token in enumerate(records.sample_tokens):
            rows = np.flatnonzero(samples == sample_token)
            if len(rows) == 0 or rig_of[position] < 0:
                continue
            with self._timed("read"):
                inputs = self._inputs(detections, frustums, rows)
            if len(inputs.detection_id) == 0:
                continue
            tables.append(self._sample(records, position, rigs[rig_of[position]], inputs, detections_path))
        table = pa.concat_tables(tables) if tables else BOXES_SCHEMA.empty_table()
        timings = {"samples": len(records.sample_tokens), **{stage: self.seconds.get(stage, 0) for stage in STAGES}}
        return table.replace_schema_metadata({"sianms.timings": json.dumps(timings)})

    # ----------------------------------------------------------------------- inputs

    def _inputs(self, detections: pa.Table, frustums: tuple[np.ndarray, RaggedPoints], rows: np.ndarray
                ) -> SampleInputs:
        """The sample's detections that Frustum PointNets takes (module docstring, step 1)."""
        table = detections.take(pa.array(rows))
        rot_angle, ragged = frustums
        boxes = np.stack([table[c].to_numpy() for c in ("x1", "y1", "x2", "y2")], axis=1).astype(np.float64)
        classes = table["class"].to_numpy(zero_copy_only=False).astype(str)
        counts = ragged.count[rows]
        keep = (np.isin(classes, self.predictor.classes)
                & (table["source"].to_numpy(zero_copy_only=False).astype(str) == "detector")
                & (boxes[:, 3] - boxes[:, 1] >= self.predictor.min_box_height) & (counts > 0))
        kept = rows[keep]
        points, offsets = ragged.take(kept)
        instance = table["instance_token"].fill_null("").to_numpy(zero_copy_only=False).astype(str)
        return SampleInputs(
            detection_id=table["detection_id"].to_numpy(zero_copy_only=False).astype(str)[keep],
            camera=table["camera"].to_numpy(zero_copy_only=False).astype(str)[keep],
            boxes2d=boxes[keep], score=table["score"].to_numpy().astype(np.float64)[keep], classes=classes[keep],
            instance=instance[keep], points=points, offsets=offsets, rot_angle=rot_angle[kept])

    # ----------------------------------------------------------------------- one sample

    def _sample(self, records: SceneRecords, position: int, rig: CameraRig, inputs: SampleInputs,
                detections_path: Path) -> pa.Table:
        settings = self.settings
        cameras = self._camera_frames(records, position)
        cam_to_global = np.stack([cameras[c][0] for c in inputs.camera])
        with self._timed("fpointnet_single"):
            single = self.predictor.predict(inputs.points, inputs.offsets, inputs.classes,
                                            f"{SINGLE}:{records.sample_tokens[position]}", settings.seed)
        boxes = frustum_boxes_to_global(single["center"], single["heading"], single["lwh"], inputs.rot_angle,
                                        cam_to_global)
        rows = [_rows(records, position, SINGLE, inputs, np.arange(len(inputs.detection_id)), None, boxes,
                      counts=np.diff(inputs.offsets))]
        with self._timed("candidates"):
            candidates = self._candidates(rig, inputs)
        matchers = [(SIANMS, self._network_matches(candidates, inputs, detections_path,
                                                   records.sample_tokens[position])),
                    (ORACLE, self._oracle_matches(candidates, inputs))]
        lidar = None
        for kind, (first, second, distance) in matchers:
            if len(first) == 0:
                continue
            if lidar is None:
                with self._timed("read"):
                    lidar = lidar_points_global(self.db, records, position)
            rows.append(self._merged(records, position, kind, inputs, first, second, distance, cameras, lidar))
        return pa.concat_tables(rows)

    def _camera_frames(self, records: SceneRecords, position: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """{channel: (camera -> global (4, 4), intrinsic (3, 3))} of the sample's key frames."""
        frames, keyframes = {}, records.keyframes
        for c, channel in enumerate(records.channels):
            if keyframes.rows[position, c] < 0 or np.isnan(keyframes.intrinsic[position, c]).all():
                continue
            frames[channel] = (sensor_to_global(keyframes.ego_rotation[position, c],
                                                keyframes.ego_translation[position, c],
                                                keyframes.sensor_rotation[position, c],
                                                keyframes.sensor_translation[position, c]),
                               keyframes.intrinsic[position, c])
        return frames

    def span(self, rig: CameraRig, a: int, b: int) -> tuple[float, float] | None:
        """Camera a's image columns camera b also sees (cached per rig)."""
        spans = self._spans.setdefault(rig, {})
        if (a, b) not in spans:
            rotation = rig.ego_to_cam[b, :3, :3] @ rig.cam_to_ego[a, :3, :3]
            spans[a, b] = overlap_columns(rig.intrinsics[a], tuple(rig.image_sizes[a]), rotation,
                                          rig.intrinsics[b], tuple(rig.image_sizes[b]))
        return spans[a, b]

    def _candidates(self, rig: CameraRig, inputs: SampleInputs) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per contiguous pair (clockwise), the candidate rows of each camera (module docstring, step 3)."""
        matched = np.isin(inputs.classes, self.settings.matched_classes)
        pairs = []
        for a, b in rig.contiguous_pairs:
            in_a = matched & (inputs.camera == rig.channels[a]) & in_columns(inputs.boxes2d, self.span(rig, a, b))
            in_b = matched & (inputs.camera == rig.channels[b]) & in_columns(inputs.boxes2d, self.span(rig, b, a))
            pairs.append((np.flatnonzero(in_a), np.flatnonzero(in_b)))
        return pairs

    def _network_matches(self, candidates: list[tuple[np.ndarray, np.ndarray]], inputs: SampleInputs,
                         detections_path: Path, sample_token: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(first rows, second rows, distances) of the siamese network's matches."""
        rows = np.unique(np.concatenate([np.concatenate(pair) for pair in candidates] + [np.zeros(0, np.int64)]))
        if len(rows) == 0:
            return _no_matches()
        with self._timed("embed"):
            computed = self._embed(detections_path, sample_token, inputs.detection_id[rows])
            embedding = np.zeros((len(inputs.detection_id), computed.shape[1]))
            embedding[rows] = computed

        def match(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            with self._timed("assign"):
                distance = pair_distances(embedding[a], embedding[b])
                allowed = allowed_pairs(distance, inputs.classes[a], inputs.classes[b], self.settings.dis_thr,
                                        self.settings.matched_classes)
                i, j = assign(distance, allowed)
            return a[i], b[j], distance[i, j]

        return _match_pairs(candidates, match)

    def _oracle_matches(self, candidates: list[tuple[np.ndarray, np.ndarray]],
                        inputs: SampleInputs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        def match(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            i, j = oracle_matches(inputs.instance[a], inputs.instance[b], inputs.classes[a], inputs.classes[b],
                                  self.settings.matched_classes)
            return a[i], b[j], np.full(len(i), np.nan)

        return _match_pairs(candidates, match)

    def _embed(self, detections_path: Path, sample_token: str, detection_ids: np.ndarray) -> np.ndarray:
        """(R, d) embeddings of some detections of one sample, read from the detections file.

        prepare writes a row group per sample, so the filter reads only this sample's features.
        """
        from sianms_cli.training.siamese import embed

        table = read_shard_table(detections_path, columns=["detection_id", "roi_feature"],
                                 filters=[("sample_token", "==", sample_token)])
        where = pc.index_in(pa.array(detection_ids.tolist(), pa.string()),
                            value_set=table["detection_id"].combine_chunks())
        features = table["roi_feature"].take(where)
        shape = roi_feature_shape(detections_path)
        return embed(self.encoder, decode_roi_features(features, shape, detections_path))

    def _merged(self, records: SceneRecords, position: int, kind: str, inputs: SampleInputs, first: np.ndarray,
                second: np.ndarray, distance: np.ndarray, cameras: dict, lidar: tuple[np.ndarray, np.ndarray]
                ) -> pa.Table:
        """Rows of one matcher's matches: dismissed ones without a box, the others from their union frustum."""
        settings = self.settings
        points_global, point_extra = lidar
        frames_a = [cameras[c] for c in inputs.camera[first]]
        frames_b = [cameras[c] for c in inputs.camera[second]]
        geometry = pair_geometry(inputs.boxes2d[first], inputs.boxes2d[second], np.stack([f[0] for f in frames_a]),
                                 np.stack([f[0] for f in frames_b]), np.stack([f[1] for f in frames_a]),
                                 np.stack([f[1] for f in frames_b]), settings.max_distance)
        overlap, angle = geometry.overlap, geometry.angle
        frustums, counts = [], np.zeros(len(first), dtype=np.int64)
        with self._timed("union_frustums"):
            for k in np.flatnonzero(overlap):
                inside, union = pair_union(points_global, geometry, k, inputs.boxes2d[[first[k], second[k]]],
                                           (frames_a[k][1], frames_b[k][1]), settings.min_depth, settings.max_depth)
                counts[k] = inside.sum()
                frustums.append(np.concatenate([union, point_extra[inside, :1]], axis=1))
        boxed = np.flatnonzero(overlap & (counts > 0))
        offsets = np.concatenate([[0], np.cumsum(counts[boxed])]).astype(np.int64)
        points = np.concatenate(frustums + [np.zeros((0, 4))]) if frustums else np.zeros((0, 4))
        with self._timed("fpointnet_union"):
            predicted = self.predictor.predict(points, offsets, inputs.classes[first[boxed]],
                                               f"{kind}:{records.sample_tokens[position]}", settings.seed)
        cam_to_global = np.stack([frames_a[k][0] for k in boxed]) if len(boxed) else np.zeros((0, 4, 4))
        merged = frustum_boxes_to_global(predicted["center"], predicted["heading"], predicted["lwh"], angle[boxed],
                                         cam_to_global)
        full = GlobalBoxes(translation=np.full((len(first), 3), np.nan), size=np.full((len(first), 3), np.nan),
                           yaw=np.full(len(first), np.nan))
        full.translation[boxed], full.size[boxed], full.yaw[boxed] = merged.translation, merged.size, merged.yaw
        return _rows(records, position, kind, inputs, first, second, full, counts=counts, distance=distance,
                     dismissed=~overlap | (counts == 0),
                     wedges=geometry.wedges[..., :2].reshape(-1, 12))


# --------------------------------------------------------------------------- helpers


def _no_matches() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0)


def _match_pairs(candidates: list[tuple[np.ndarray, np.ndarray]], match) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Matches of every pair in order; a detection matched once is not a candidate again."""
    taken: set[int] = set()
    firsts, seconds, distances = [], [], []
    for a, b in candidates:
        a = np.array([r for r in a.tolist() if r not in taken], dtype=np.int64)
        b = np.array([r for r in b.tolist() if r not in taken], dtype=np.int64)
        if len(a) == 0 or len(b) == 0:
            continue
        first, second, distance = match(a, b)
        taken.update(first.tolist() + second.tolist())
        firsts.append(first)
        seconds.append(second)
        distances.append(distance)
    if not firsts:
        return _no_matches()
    return np.concatenate(firsts), np.concatenate(seconds), np.concatenate(distances)


@dataclass(frozen=True, eq=False)
class RaggedPoints:
    """Points of several frustums concatenated: frustum n is ``points[start[n]:start[n] + count[n]]``."""

    points: np.ndarray  # (M, 4) x, y, z, raw intensity
    start: np.ndarray
    count: np.ndarray

    def take(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(points, offsets (R + 1,)) of the frustums ``rows``, in that order."""
        count = self.count[rows]
        offsets = np.concatenate([[0], np.cumsum(count)]).astype(np.int64)
        index = np.repeat(self.start[rows] - offsets[:-1], count) + np.arange(offsets[-1])
        return self.points[index], offsets


def _frustum_points(table: pa.Table, detection_ids: pa.ChunkedArray) -> tuple[np.ndarray, RaggedPoints]:
    """Each detection's rot_angle (NaN without a frustum) and frustum points, aligned with ``detection_ids``."""
    where = pc.index_in(detection_ids, value_set=table["detection_id"].combine_chunks())
    found = where.is_valid().to_numpy(zero_copy_only=False)
    where = where.fill_null(0).to_numpy(zero_copy_only=False).astype(np.int64)
    counts = pc.list_value_length(table["x"]).to_numpy(zero_copy_only=False).astype(np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    points = np.stack([pc.list_flatten(table[c]).to_numpy() for c in ("x", "y", "z", "intensity")], axis=1)
    rot_angle = np.where(found, table["rot_angle"].to_numpy().astype(np.float64)[where], np.nan)
    return rot_angle, RaggedPoints(points.astype(np.float64), offsets[where], np.where(found, counts[where], 0))


def vector_column(rows: np.ndarray, valid: np.ndarray) -> pa.ListArray:
    """The rows of an (n, k) array as a list column, null where not ``valid``; a null row holds no
    values, which every pyarrow the package supports writes and reads."""
    lengths = np.where(valid, rows.shape[1], 0)
    offsets = pa.array(np.concatenate([[0], np.cumsum(lengths)]).astype(np.int32))
    return pa.ListArray.from_arrays(offsets, pa.array(rows[valid].ravel(), pa.float64()), mask=pa.array(~valid))


def _rows(records: SceneRecords, position: int, kind: str, inputs: SampleInputs, first: np.ndarray,
          second: np.ndarray | None, boxes: GlobalBoxes, *, counts: np.ndarray, distance: np.ndarray | None = None,
          dismissed: np.ndarray | None = None, wedges: np.ndarray | None = None) -> pa.Table:
    """Boxes-table rows of single boxes (``second`` None) or matches."""
    count = len(first)
    ids = inputs.detection_id
    missing = [None] * count
    correct = (None if second is None
               else (inputs.instance[first] == inputs.instance[second]) & (inputs.instance[first] != ""))
    valid = np.isfinite(boxes.yaw)
    return pa.table({
        "scene_token": [records.scene_token] * count,
        "sample_token": [records.sample_tokens[position]] * count,
        "kind": [kind] * count,
        "detection_a": ids[first].tolist(),
        "detection_b": missing if second is None else ids[second].tolist(),
        "camera_a": inputs.camera[first].tolist(),
        "camera_b": missing if second is None else inputs.camera[second].tolist(),
        "class": inputs.classes[first].tolist(),
        "score": (inputs.score[first] if second is None else np.maximum(inputs.score[first], inputs.score[second])
                  ).astype(np.float32),
        "distance": pa.array(missing if distance is None else distance.astype(np.float32), pa.float32(),
                             from_pandas=True),
        "dismissed": np.zeros(count, bool) if dismissed is None else dismissed,
        "correct": pa.array(missing if correct is None else correct.tolist(), pa.bool_()),
        "num_points": counts.astype(np.int32),
        "translation": vector_column(boxes.translation, valid),
        "size": vector_column(boxes.size, valid),
        "yaw": pa.array(np.where(valid, boxes.yaw, np.nan), pa.float64(), from_pandas=True),
        "wedges": (pa.nulls(count, pa.list_(pa.float64())) if wedges is None
                   else vector_column(wedges, np.ones(count, bool))),
    }, schema=BOXES_SCHEMA)
