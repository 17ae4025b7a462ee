"""One key frame of `sianms prepare` as a pipeline on arrays.

Per camera of the sample's rig (:meth:`Preparer._camera`):

1. the sample's annotations, moved into the camera frame, become the image's 2D ground truth
   (:func:`sianms_cli.prepare.ground_truth.camera_ground_truth`);
2. a :class:`~sianms_cli.detection2d.detectors.Detector` gives the image's detections;
3. they are associated with the ground truth of the prepared classes by 2D IoU, and on
   training splits the missed objects are added as detections of source ``ground_truth``;
4. ROI features (:func:`~sianms_cli.detection2d.roi_features.roi_features`) and LiDAR
   frustums (:func:`~sianms_cli.data.frustums.extract_frustums`) of all its detections at once.

The cameras' rows are concatenated (:class:`PreparedDetections`) and each of the three tables
is built once from these column arrays, with the schemas declared in
:mod:`sianms_cli.data.schemas`; pairs come from
:func:`~sianms_cli.data.pairs.contiguous_pairs` and the overlap region from
:func:`~sianms_cli.nuscenes.overlap.box_overlap_pairs`, the rule `info` and `metrics` use.
What a sample needs from the tables (key frames, poses, calibrations, annotations, overlap) is
fetched for its whole scene in one vectorised pass (:func:`scene_records`).
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, fields

import numpy as np
import pyarrow as pa

from sianms_cli.data.frustums import Frustums, extract_frustums
from sianms_cli.data.pairs import contiguous_pairs
from sianms_cli.data.schemas import cache_schemas
from sianms_cli.detection2d.association import associate
from sianms_cli.detection2d.backbones import build_backbone
from sianms_cli.detection2d.classes import detection_classes_of
from sianms_cli.detection2d.detections import Detections2D, GroundTruth2D
from sianms_cli.detection2d.detectors import build_detector
from sianms_cli.detection2d.roi_features import roi_feature_shape, roi_features
from sianms_cli.geometry.camera_ring import CameraRig
from sianms_cli.geometry.transforms import apply_transform, global_to_sensor, sensor_to_global, transform_boxes
from sianms_cli.nuscenes.keyframes import SensorRecords, keyframe_rows, sensor_records, sweep_rows
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.overlap import LIDAR_CHANNEL, OverlapBits, box_overlap_pairs
from sianms_cli.prepare.config import PrepareConfig
from sianms_cli.prepare.ground_truth import camera_ground_truth

DETECTOR = "detector"
GROUND_TRUTH = "ground_truth"


# ------------------------------------------------------------------------------ one scene's records


@dataclass(frozen=True, eq=False)
class SceneRecords:
    """What the samples of one scene need from the tables, fetched in one vectorised pass.

    Attributes:
        scene_token: the scene.
        sample_tokens: (S,) its samples, in time order.
        annotations: (A,) int64 sample_annotation rows, grouped by sample in ``sample_tokens``
            order, file order within a sample (the devkit's ``sample['anns']``).
        annotation_offsets: (S + 1,) the annotations of sample s are
            ``annotations[annotation_offsets[s]:annotation_offsets[s + 1]]``.
        overlap: THE overlap pairs of every annotation, aligned with ``annotations``.
        channels: the camera channels of the dataset, then LIDAR_TOP.
        keyframes: (S, len(channels)) the samples' key frames of each channel.
        sweeps: (S, sweeps + 1) each sample's LIDAR_TOP key frame and the sweeps before it.
    """

    scene_token: str
    sample_tokens: tuple[str, ...]
    annotations: np.ndarray
    annotation_offsets: np.ndarray
    overlap: OverlapBits
    channels: tuple[str, ...]
    keyframes: SensorRecords
    sweeps: SensorRecords

    def position(self, sample_token: str) -> int:
        """The index of a sample in ``sample_tokens``."""
        return self.sample_tokens.index(sample_token)

    def annotation_slice(self, position: int) -> slice:
        """Where the annotations of the sample at ``position`` lie in ``annotations``."""
        return slice(int(self.annotation_offsets[position]), int(self.annotation_offsets[position + 1]))


def scene_records(db: NuScenesDB, scene_token: str, sweeps: int) -> SceneRecords:
    """The records of a scene's samples (see :class:`SceneRecords`), ``sweeps`` LiDAR sweeps deep."""
    tokens = tuple(db.sample_tokens_of_scene(scene_token))
    sample_rows = db.table("sample").indices(list(tokens))
    position = np.full(len(db.table("sample")), -1, dtype=np.int64)
    position[sample_rows] = np.arange(len(tokens))
    annotations = db.table("sample_annotation")
    owner = position[annotations.rows("sample_token")]
    rows = np.flatnonzero(owner >= 0)
    rows = rows[np.argsort(owner[rows], kind="stable")]
    offsets = np.searchsorted(owner[rows], np.arange(len(tokens) + 1))
    sensors = db.table("sensor")
    channels = (*sensors.column("channel")[sensors.column("modality") == "camera"].tolist(), LIDAR_CHANNEL)
    keyframes = keyframe_rows(db, sample_rows, channels)
    return SceneRecords(
        scene_token=scene_token,
        sample_tokens=tokens,
        annotations=rows,
        annotation_offsets=offsets,
        overlap=box_overlap_pairs(db, tokens, owner[rows], annotations.column("translation")[rows]),
        channels=channels,
        keyframes=sensor_records(db, keyframes),
        sweeps=sensor_records(db, sweep_rows(db, keyframes[:, -1], sweeps)),
    )


def lidar_points_global(db: NuScenesDB, scene: SceneRecords, position: int) -> tuple[np.ndarray, np.ndarray]:
    """A sample's key-frame sweep (+ the earlier sweeps of ``scene``) in the global frame.

    Returns:
        (P, 3) xyz and (P, 2) [intensity, time lag before the key frame (s)].
    """
    sweeps = scene.sweeps
    xyz, extra = [np.zeros((0, 3))], [np.zeros((0, 2))]
    for k in np.flatnonzero(sweeps.rows[position] >= 0).tolist():
        points = db.read_lidar(str(sweeps.tokens[position, k]))
        to_global = sensor_to_global(sweeps.ego_rotation[position, k], sweeps.ego_translation[position, k],
                                     sweeps.sensor_rotation[position, k], sweeps.sensor_translation[position, k])
        xyz.append(apply_transform(to_global, points[:, :3]))
        lag = (sweeps.timestamps[position, 0] - sweeps.timestamps[position, k]) / 1e6
        extra.append(np.stack([points[:, 3], np.full(len(points), lag)], axis=1))
    return np.concatenate(xyz), np.concatenate(extra)


# ------------------------------------------------------------------------------ detections as columns


@dataclass(frozen=True, eq=False)
class PreparedDetections:
    """Detections with everything the three tables take from them: D aligned rows.

    Made per camera image (:meth:`Preparer._camera`), then concatenated over the sample's
    cameras in rig order; within an image the rows are in rank order (the detector's by
    descending score, then the filled-in missed objects).

    Attributes:
        camera: (D,) int64 index of the camera in the sample's rig.
        sample_data_token: (D,) str the image.
        rank: (D,) int64 index of the detection in its image.
        image_size: (D, 2) int64 (W, H) pixels.
        boxes, scores, classes: (D, 4) [x1, y1, x2, y2] pixels, (D,), (D,) str.
        source: (D,) str ``detector`` or ``ground_truth``.
        annotation: (D,) int64 index of the associated annotation in the sample, -1 for none.
        iou: (D,) IoU with the associated ground-truth box, 0 for none.
        truncation, occlusion, distance: (D,) of the associated ground truth, NaN for none.
        features: (D, C, PH, PW) little-endian float16 ROI features.
        frustums: the D LiDAR frustums.
    """

    camera: np.ndarray
    sample_data_token: np.ndarray
    rank: np.ndarray
    image_size: np.ndarray
    boxes: np.ndarray
    scores: np.ndarray
    classes: np.ndarray
    source: np.ndarray
    annotation: np.ndarray
    iou: np.ndarray
    truncation: np.ndarray
    occlusion: np.ndarray
    distance: np.ndarray
    features: np.ndarray
    frustums: Frustums

    def __len__(self) -> int:
        return len(self.rank)

    @property
    def associated(self) -> np.ndarray:
        """(D,) bool: the detection has an associated annotation."""
        return self.annotation >= 0

    @property
    def detection_ids(self) -> np.ndarray:
        """(D,) str ``<sample_data_token>_<rank>``, the rank zero-padded to four digits."""
        return np.char.add(np.char.add(self.sample_data_token, "_"), np.char.zfill(self.rank.astype(str), 4))

    @staticmethod
    def concatenate(parts: list[PreparedDetections]) -> PreparedDetections:
        """The rows of several images one after the other (at least one part)."""
        columns = {field.name: np.concatenate([getattr(part, field.name) for part in parts])
                   for field in fields(PreparedDetections) if field.name != "frustums"}
        return PreparedDetections(frustums=Frustums.concatenate([part.frustums for part in parts]), **columns)


def associate_and_fill(detections: Detections2D, target: GroundTruth2D, iou_threshold: float,
                       fills_missed: bool) -> tuple[Detections2D, np.ndarray, np.ndarray, np.ndarray]:
    """Associate detections with the ground truth by 2D IoU; on training splits add the missed objects.

    A missed object becomes a detection of score 1 and source ``ground_truth``, unless it is
    fully hidden by nearer ones (occlusion 1): no detector could find it.

    Returns:
        ``(detections, match, iou, source)``: the detections (filled-in ones last), the (D,)
        matched row of ``target`` or -1, the (D,) IoU with it, the (D,) source.
    """
    match, iou = associate(detections.boxes, target.boxes, iou_threshold, detections.classes, target.classes)
    source = np.full(len(detections), DETECTOR)
    if not fills_missed:
        return detections, match, iou, source
    missed = np.setdiff1d(np.arange(len(target)), match[match >= 0])
    missed = missed[target.occlusion[missed] < 1.0]
    fill = Detections2D(target.boxes[missed], np.ones(len(missed)), target.classes[missed])
    return (Detections2D.concatenate([detections, fill]), np.concatenate([match, missed]),
            np.concatenate([iou, np.ones(len(missed))]), np.concatenate([source, np.full(len(missed), GROUND_TRUTH)]))


def _gather(values: np.ndarray, index: np.ndarray, missing: float | int | str = np.nan) -> np.ndarray:
    """``values[index]``, with ``missing`` where ``index`` is -1 (it selects an appended last row)."""
    padded = np.concatenate([values, np.full((1,) + values.shape[1:], missing, dtype=values.dtype)])
    return padded[index]


# ------------------------------------------------------------------------------ the preparer


class Preparer:
    """The loaded state one process needs: dataset, detector, backbone, the current scene's records."""

    def __init__(self, config: PrepareConfig, db: NuScenesDB | None = None) -> None:
        self.config = config
        self.db = db if db is not None else NuScenesDB(config.dataroot, config.version)
        self.detector = build_detector(config.detector, self.db, config.classes)
        self.backbone = build_backbone(config.backbone, config.weights, seed=config.seed)
        annotations = self.db.table("sample_annotation")
        self.ann_classes = detection_classes_of(self.db.annotation_category_names())
        self.ann_tokens = annotations.tokens
        self.ann_instances = annotations.column("instance_token")
        self.ann_center = annotations.column("translation")
        self.ann_size = annotations.column("size")
        self.ann_rotation = annotations.column("rotation")
        self.schemas = cache_schemas(roi_feature_shape(self.backbone, config.roi_size), config.backbone)
        self._scene: SceneRecords | None = None

    def _scene_records(self, scene_token: str) -> SceneRecords:
        """The records of ``scene_token``, fetched on its first sample (shards are whole scenes)."""
        if self._scene is None or self._scene.scene_token != scene_token:
            self._scene = scene_records(self.db, scene_token, self.config.sweeps)
        return self._scene

    def sample(self, scene_token: str, scene_name: str, sample_token: str, rig: CameraRig) -> dict[str, pa.Table]:
        """The rows of one key frame in the three datasets, by dataset name."""
        scene = self._scene_records(scene_token)
        position = scene.position(sample_token)
        mine = scene.annotation_slice(position)
        rows = scene.annotations[mine]
        points_global, point_extra = lidar_points_global(self.db, scene, position)
        cameras = [camera for camera in (self._camera(scene, position, cam, rig, rows, points_global, point_extra)
                                         for cam in range(len(rig.channels))) if camera is not None]
        if not cameras:
            return {name: schema.empty_table() for name, schema in self.schemas.items()}
        detections = PreparedDetections.concatenate(cameras)
        overlap = scene.overlap.pairs(rig.pair_names)[mine]  # (A, pairs of the rig)
        instances = _gather(self.ann_instances[rows], detections.annotation, missing="")
        ids = {"scene_token": scene_token, "scene_name": scene_name, "sample_token": sample_token}
        return {
            "detections": detections_table(self.schemas["detections"], ids, detections, rig, instances,
                                           _gather(self.ann_tokens[rows], detections.annotation, missing=""),
                                           _gather(overlap, detections.annotation, missing=False)),
            "frustums": frustums_table(self.schemas["frustums"], ids, detections, rig, instances),
            "pairs": pairs_table(self.schemas["pairs"], ids, detections, rig, instances, overlap),
        }

    def _camera(self, scene: SceneRecords, position: int, cam: int, rig: CameraRig, rows: np.ndarray,
                points_global: np.ndarray, point_extra: np.ndarray) -> PreparedDetections | None:
        """One camera image's detections, associated, filled in, pooled, with their frustums; None without any."""
        config, records = self.config, scene.keyframes
        c = scene.channels.index(rig.channels[cam])
        token = str(records.tokens[position, c])
        to_cam = global_to_sensor(records.ego_rotation[position, c], records.ego_translation[position, c],
                                  records.sensor_rotation[position, c], records.sensor_translation[position, c])
        intrinsic = records.intrinsic[position, c]
        image_size = (int(rig.image_sizes[cam][0]), int(rig.image_sizes[cam][1]))
        center_cam, rotation_cam = transform_boxes(to_cam, self.ann_center[rows], self.ann_rotation[rows])
        size = self.ann_size[rows]
        gt = camera_ground_truth(self.ann_classes[rows], center_cam, size, rotation_cam, intrinsic, image_size)
        rng = np.random.default_rng([config.seed, zlib.crc32(token.encode())])
        target = gt.subset(np.isin(gt.classes, config.classes))
        detections, match, iou, source = associate_and_fill(
            self.detector.detections(token, gt, image_size, rng), target, config.iou_threshold, config.fills_missed)
        count = len(detections)
        if count == 0:
            return None
        annotation = _gather(target.ids, match, missing=-1)
        frustums = extract_frustums(
            apply_transform(to_cam, points_global), point_extra, detections.boxes, intrinsic,
            _gather(center_cam, annotation), _gather(size, annotation), _gather(rotation_cam, annotation),
            annotation >= 0, config.min_depth, np.inf if config.max_depth is None else config.max_depth)
        features = roi_features(self.backbone, self.db.read_image(token), detections.boxes, config.roi_size,
                                config.sampling_ratio)
        return PreparedDetections(
            camera=np.full(count, cam), sample_data_token=np.full(count, token), rank=np.arange(count),
            image_size=np.tile(image_size, (count, 1)), boxes=detections.boxes, scores=detections.scores,
            classes=np.asarray(detections.classes, dtype=str), source=source, annotation=annotation, iou=iou,
            truncation=_gather(target.truncation, match), occlusion=_gather(target.occlusion, match),
            distance=_gather(target.distance, match), features=features, frustums=frustums)


# ------------------------------------------------------------------------------ the three tables


def _strings(values: np.ndarray, valid: np.ndarray | None = None) -> pa.Array:
    """A string column; null where ``valid`` is false."""
    return pa.array(np.asarray(values, dtype=str), type=pa.string(), mask=None if valid is None else ~valid)


def _float32(values: np.ndarray, valid: np.ndarray | None = None) -> pa.Array:
    """A float32 column (rounded to nearest from float64); null where ``valid`` is false."""
    return pa.array(np.asarray(values, dtype=np.float64).astype(np.float32), type=pa.float32(),
                    mask=None if valid is None else ~valid)


def _lists(values: np.ndarray, counts: np.ndarray, value_type: pa.DataType,
           valid: np.ndarray | None = None) -> pa.Array:
    """A list column: row n holds the next ``counts[n]`` of ``values``; null where ``valid`` is false."""
    offsets = np.zeros(len(counts) + 1, dtype=np.int32)
    np.cumsum(counts, out=offsets[1:])
    return pa.ListArray.from_arrays(pa.array(offsets), pa.array(np.asarray(values), type=value_type),
                                    mask=None if valid is None else pa.array(~valid))


def _identity_columns(ids: dict[str, str], detections: PreparedDetections, rig: CameraRig,
                      instances: np.ndarray) -> dict[str, pa.Array]:
    """The columns that name a detection, shared by ``detections`` and ``frustums``."""
    count = len(detections)
    return {
        "detection_id": _strings(detections.detection_ids),
        "scene_token": _strings(np.full(count, ids["scene_token"])),
        "sample_token": _strings(np.full(count, ids["sample_token"])),
        "sample_data_token": _strings(detections.sample_data_token),
        "camera": _strings(np.asarray(rig.channels, dtype=str)[detections.camera]),
        "class": _strings(detections.classes),
        "score": _float32(detections.scores),
        "source": _strings(detections.source),
        "instance_token": _strings(instances, detections.associated),
    }


def _overlap_pair_lists(detections: PreparedDetections, rig: CameraRig, overlap: np.ndarray) -> pa.Array:
    """``overlap_pairs``: per detection, the rig pairs of its camera (in rig order) whose overlap
    holds its annotation's centre; ``overlap`` is (D, pairs of the rig), False without annotation."""
    pairs = np.asarray(rig.contiguous_pairs, dtype=np.int64).reshape(-1, 2)
    of_camera = (pairs[None, :, 0] == detections.camera[:, None]) | (pairs[None, :, 1] == detections.camera[:, None])
    hit = overlap & of_camera
    _, pair = np.nonzero(hit)
    return _lists(np.asarray(rig.pair_names, dtype=str)[pair], hit.sum(axis=1), pa.string())


def detections_table(schema: pa.Schema, ids: dict[str, str], detections: PreparedDetections, rig: CameraRig,
                     instances: np.ndarray, annotation_tokens: np.ndarray, overlap: np.ndarray) -> pa.Table:
    """The ``detections`` rows of one sample (schema in :mod:`sianms_cli.data.schemas`).

    Args:
        schema: the dataset's schema.
        ids: scene_token, scene_name, sample_token.
        detections: the sample's detections.
        rig: the sample's rig.
        instances, annotation_tokens: (D,) of each detection's annotation ("" for none).
        overlap: (D, pairs of the rig) THE overlap pairs of each detection's annotation.
    """
    columns = _identity_columns(ids, detections, rig, instances)
    associated = detections.associated
    features = np.ascontiguousarray(detections.features)
    return pa.table({
        **{name: columns[name] for name in ("detection_id", "scene_token", "sample_token", "sample_data_token",
                                            "camera")},
        "scene_name": _strings(np.full(len(detections), ids["scene_name"])),
        "detection_index": detections.rank.astype(np.int32),
        **{name: _float32(detections.boxes[:, j]) for j, name in enumerate(("x1", "y1", "x2", "y2"))},
        **{name: columns[name] for name in ("score", "class", "source")},
        "image_width": detections.image_size[:, 0].astype(np.int32),
        "image_height": detections.image_size[:, 1].astype(np.int32),
        "instance_token": columns["instance_token"],
        "annotation_token": _strings(annotation_tokens, associated),
        "iou": _float32(detections.iou),
        "gt_truncation": _float32(detections.truncation, associated),
        "gt_occlusion": _float32(detections.occlusion, associated),
        "gt_distance": _float32(detections.distance, associated),
        "overlap_pairs": _overlap_pair_lists(detections, rig, overlap),
        "roi_feature": pa.FixedSizeBinaryArray.from_buffers(schema.field("roi_feature").type, len(detections),
                                                            [None, pa.py_buffer(features.tobytes())]),
    }, schema=schema)


def frustums_table(schema: pa.Schema, ids: dict[str, str], detections: PreparedDetections, rig: CameraRig,
                   instances: np.ndarray) -> pa.Table:
    """The ``frustums`` rows of one sample: one per detection, its points as list columns."""
    columns = _identity_columns(ids, detections, rig, instances)
    frustums = detections.frustums
    counts = frustums.counts
    points = frustums.points.astype(np.float32)
    extra = frustums.extra.astype(np.float32)
    has_box = frustums.has_box

    def box_vectors(values: np.ndarray) -> pa.Array:
        width = values.shape[1]
        return _lists(values[has_box].astype(np.float32).ravel(), np.where(has_box, width, 0), pa.float32(), has_box)

    return pa.table({
        **{name: columns[name] for name in ("detection_id", "scene_token", "sample_token", "sample_data_token",
                                            "camera", "class", "score", "source", "instance_token")},
        "rot_angle": _float32(frustums.rot_angle),
        "num_points": counts.astype(np.int32),
        **{name: _lists(points[:, j], counts, pa.float32()) for j, name in enumerate(("x", "y", "z"))},
        "intensity": _lists(extra[:, 0], counts, pa.float32()),
        "time_lag": _lists(extra[:, 1], counts, pa.float32()),
        "label": _lists(frustums.labels, counts, pa.int8()),
        "box_center_cam": box_vectors(frustums.box_center_cam),
        "box_size": box_vectors(frustums.box_size),
        "box_rotation_cam": box_vectors(frustums.box_rotation_cam),
        "box_heading_cam": _float32(frustums.box_heading_cam, has_box),
        "box_center_frustum": box_vectors(frustums.box_center_frustum),
        "box_heading_frustum": _float32(frustums.box_heading_frustum, has_box),
    }, schema=schema)


def pairs_table(schema: pa.Schema, ids: dict[str, str], detections: PreparedDetections, rig: CameraRig,
                instances: np.ndarray, overlap: np.ndarray) -> pa.Table:
    """The ``pairs`` rows of one sample: each instance detected in both cameras of a contiguous pair.

    ``overlap`` is (A, pairs of the rig) THE overlap pairs of the sample's annotations: a
    pair's ``center_in_overlap`` is that of its reference detection's annotation.
    """
    rows = contiguous_pairs(detections.camera, instances, rig.contiguous_pairs)
    number, reference, positive = rows[:, 0], rows[:, 1], rows[:, 2]
    cameras = np.asarray(rig.contiguous_pairs, dtype=np.int64).reshape(-1, 2)[number]
    channels = np.asarray(rig.channels, dtype=str)
    detection_id = detections.detection_ids
    return pa.table({
        "scene_token": _strings(np.full(len(rows), ids["scene_token"])),
        "sample_token": _strings(np.full(len(rows), ids["sample_token"])),
        "instance_token": _strings(instances[reference]),
        "class": _strings(detections.classes[reference]),
        "pair": _strings(np.asarray(rig.pair_names, dtype=str)[number]),
        "camera_a": _strings(channels[cameras[:, 0]]),
        "camera_b": _strings(channels[cameras[:, 1]]),
        "reference_detection_id": _strings(detection_id[reference]),
        "positive_detection_id": _strings(detection_id[positive]),
        "reference_source": _strings(detections.source[reference]),
        "positive_source": _strings(detections.source[positive]),
        "center_in_overlap": pa.array(overlap[detections.annotation[reference], number], type=pa.bool_()),
    }, schema=schema)
