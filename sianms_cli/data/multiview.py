"""Union frustums of the cache's cross-camera pairs: Frustum PointNets' ``--multiview`` training set.

For every row of the cache's ``pairs/`` shard (a reference detection in ``camera_a``, the
positive in ``camera_b``, one instance) whose class is trained, the union frustum exactly as
``sianms eval`` builds a siaNMS match's (:mod:`sianms_cli.evaluation.multiview`, the cache's
sweeps and depth window; docs/methods.md#multi-view-frustums), in the single frustums'
conventions (:mod:`.frustums`): ``label`` 1 for the union points inside the reference
detection's ground-truth box, tested in camera_a's frame; box centre and heading in the frame
of the multi-frustum angle, which is the ``rot_angle``; raw intensity; ``score`` the higher of
the two 2-D scores. A pair is skipped where a single frustum would be (class not trained, no
box, a 2-D box under ``min_box_height``) and where a match is dismissed (wedges apart, empty
union, no object point).

**Computed once per run.** The unions need the dataroot's LiDAR sweeps, and every point of the
sample is projected into both cameras for each pair, which costs more than training on the
frustum; so each cache shard's unions are written atomically to ``<folder>/<shard>.parquet``
(:data:`UNION_SCHEMA`) and read back every epoch, so a first run and a resumed run train on the
same bytes. Each file's metadata holds a key of what made it (the shard files' SHA-256, the
dataset fingerprint, the LiDAR settings, classes, minimum box height, ``max_distance``); a file
whose key differs is recomputed.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from sianms_cli.data.cache import MANIFEST, complete_manifest, read_shard_table, shard_records, verified_shard
from sianms_cli.data.frustum_dataset import FrustumSelection, frustum_shards
from sianms_cli.data.schemas import FRUSTUMS_SCHEMA, with_metadata
from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.geometry.boxes import points_in_boxes
from sianms_cli.geometry.frustum import rotate_to_frustum
from sianms_cli.geometry.transforms import sensor_to_global
from sianms_cli.io import atomic_file, sha256_of
from sianms_cli.json_stream import is_finite_number
from sianms_cli.prepare.config import MAX_SWEEPS
from sianms_cli.progress import SILENT, Progress

UNION_DATASET = "multiview_frustums"
UNION_FORMAT = 1  # bump when the union frustums' content changes: stale files are then recomputed
KEY_FIELD = b"sianms.multiview_key"
UNION_SCHEMA = with_metadata(pa.schema(
    [FRUSTUMS_SCHEMA.field(name) for name in ("detection_id", "scene_token", "sample_token", "camera")]
    + [pa.field("positive_detection_id", pa.string()), pa.field("camera_b", pa.string())]
    + [FRUSTUMS_SCHEMA.field(name) for name in (
        "class", "score", "source", "instance_token", "rot_angle", "num_points", "x", "y", "z", "intensity", "label",
        "box_center_cam", "box_size", "box_rotation_cam", "box_heading_cam", "box_center_frustum",
        "box_heading_frustum")]), UNION_DATASET)
_PAIR_COLUMNS = ["scene_token", "sample_token", "instance_token", "class", "camera_a", "camera_b",
                 "reference_detection_id", "positive_detection_id"]
_DETECTION_COLUMNS = ["detection_id", "x1", "y1", "x2", "y2", "score"]
_BOX_COLUMNS = ["detection_id", "source", "box_center_cam", "box_size", "box_rotation_cam", "box_heading_cam"]


@dataclass(frozen=True)
class MultiviewSettings:
    """What the union frustums of a cache depend on besides its shards.

    Attributes:
        dataroot: the nuScenes dataroot the cache was prepared from (its LiDAR sweeps).
        version: the dataset version (the cache's).
        dataset_sha256: the cache's dataset fingerprint (checked against ``dataroot``).
        sweeps, min_depth, max_depth: the cache's LiDAR settings (``max_depth`` inf for none).
        max_distance: radius of the multi-frustum circle C_d and wedge depth, metres.
    """

    dataroot: str
    version: str
    dataset_sha256: str
    sweeps: int
    min_depth: float
    max_depth: float
    max_distance: float


def multiview_settings(cache: str | Path, dataroot: str, max_distance: float) -> MultiviewSettings:
    """The settings of ``cache``'s union frustums, its LiDAR settings read from its manifest."""
    config = complete_manifest(cache)["config"]
    path = Path(cache) / MANIFEST

    def setting(name: str, default: Any, holds: Callable[[Any], bool], expected: str) -> Any:
        value = config.get(name, default)
        if not holds(value):  # prepare wrote it: an edit
            raise DataFormatError(path, f"expected {expected}, got {value!r}", field=f"config.{name}")
        return value

    min_depth = setting("min_depth", 1.0, lambda v: is_finite_number(v) and v >= 0, "a finite number >= 0")
    max_depth = setting("max_depth", None, lambda v: v is None or (is_finite_number(v) and v > min_depth),
                        "null or a finite number above min_depth")
    sweeps = setting("sweeps", 0, lambda v: type(v) is int and 0 <= v <= MAX_SWEEPS, f"a whole number in "
                     f"[0, {MAX_SWEEPS}]")
    return MultiviewSettings(dataroot=str(dataroot), version=setting("version", "", _is_text, "a string"),
                             dataset_sha256=setting("dataset_sha256", "", _is_text, "a string"), sweeps=sweeps,
                             min_depth=float(min_depth), max_depth=math.inf if max_depth is None else float(max_depth),
                             max_distance=float(max_distance))


def _is_text(value: Any) -> bool:
    return isinstance(value, str)


def shard_key(cache: str | Path, shard: str, selection: FrustumSelection, settings: MultiviewSettings,
              records: dict[str, dict[str, Any]] | None = None) -> str:
    """Hex SHA-256 of what a shard's union frustums are made of (module docstring)."""
    cache = Path(cache)
    record = (shard_records(cache) if records is None else records).get(shard)
    files = {}
    for dataset in ("detections", "frustums", "pairs"):
        name = f"{dataset}/{shard}.parquet"
        known = (record or {}).get("files", {}).get(name, {}).get("sha256")
        files[name] = known or sha256_of(cache / name)
    content = {"format": UNION_FORMAT, "files": files, "dataset_sha256": settings.dataset_sha256,
               "sweeps": settings.sweeps, "min_depth": settings.min_depth, "max_depth": repr(settings.max_depth),
               "max_distance": settings.max_distance, "classes": list(selection.classes),
               "min_box_height": selection.min_box_height}
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()


def _lookup(table: pa.Table, ids: pa.ChunkedArray, path: Path, what: str) -> np.ndarray:
    """Rows of ``table`` (by ``detection_id``) of each id in ``ids``; a missing id is a format error."""
    where = pc.index_in(ids, value_set=table["detection_id"].combine_chunks())
    if where.null_count:
        raise DataFormatError(path, f"a pair's {what} detection is missing from this file", field="detection_id")
    return where.to_numpy(zero_copy_only=False).astype(np.int64)


def _camera_frame(records, position: int, channel: str) -> tuple[np.ndarray, np.ndarray]:
    """(camera -> global (4, 4), intrinsic (3, 3)) of a channel's key frame of one sample."""
    keyframes = records.keyframes
    c = records.channels.index(channel)
    if keyframes.rows[position, c] < 0 or np.isnan(keyframes.intrinsic[position, c]).all():
        raise SianmsError(f"sample {records.sample_tokens[position]} has no {channel} key frame in the dataroot; "
                          "is --dataroot the dataset the cache was prepared from?")
    return (sensor_to_global(keyframes.ego_rotation[position, c], keyframes.ego_translation[position, c],
                             keyframes.sensor_rotation[position, c], keyframes.sensor_translation[position, c]),
            keyframes.intrinsic[position, c])


def union_frustums(db, cache: str | Path, shard: str, selection: FrustumSelection,
                   settings: MultiviewSettings) -> pa.Table:
    """The union frustums of one cache shard's pairs (module docstring), a table of :data:`UNION_SCHEMA`.

    Rows follow the ``pairs/`` file's order; the LiDAR points of each sample are read once.

    Args:
        db: the :class:`~sianms_cli.nuscenes.loader.NuScenesDB` the cache was prepared from.
        cache: the cache folder.
        shard: the shard's name (``pairs/<shard>.parquet``).
        selection: the run's classes and minimum 2-D box height.
        settings: the LiDAR settings and ``max_distance``.
    """
    from sianms_cli.evaluation.multiview import pair_geometry, pair_union
    from sianms_cli.prepare.sample import lidar_points_global, scene_records

    cache = Path(cache)
    pairs_path, detections_path, frustums_path = (verified_shard(cache, dataset, shard)
                                                  for dataset in ("pairs", "detections", "frustums"))
    pairs = read_shard_table(pairs_path, columns=_PAIR_COLUMNS)
    pairs = pairs.filter(pc.is_in(pairs["class"], pa.array(list(selection.classes))))
    detections = read_shard_table(detections_path, columns=_DETECTION_COLUMNS)
    boxes_table = read_shard_table(frustums_path, columns=_BOX_COLUMNS)
    row_a = _lookup(detections, pairs["reference_detection_id"], detections_path, "reference")
    row_b = _lookup(detections, pairs["positive_detection_id"], detections_path, "positive")
    box_row = _lookup(boxes_table, pairs["reference_detection_id"], frustums_path, "reference")
    corners = np.stack([detections[c].to_numpy().astype(np.float64) for c in ("x1", "y1", "x2", "y2")], axis=1)
    boxes_a, boxes_b = corners[row_a], corners[row_b]
    has_box = boxes_table["box_center_cam"].is_valid().to_numpy(zero_copy_only=False)[box_row]
    tall = np.minimum(boxes_a[:, 3] - boxes_a[:, 1], boxes_b[:, 3] - boxes_b[:, 1]) >= selection.min_box_height
    keep = np.flatnonzero(has_box & tall)
    if len(keep) == 0:
        return UNION_SCHEMA.empty_table()

    def fixed(column: str, width: int) -> np.ndarray:
        values = boxes_table[column].take(pa.array(box_row[keep]))
        return pc.list_flatten(values).to_numpy().astype(np.float64).reshape(-1, width)

    center_cam, size, rotation = fixed("box_center_cam", 3), fixed("box_size", 3), fixed("box_rotation_cam", 4)
    heading_cam = boxes_table["box_heading_cam"].to_numpy().astype(np.float64)[box_row[keep]]
    scores = detections["score"].to_numpy().astype(np.float32)
    score = np.maximum(scores[row_a[keep]], scores[row_b[keep]])
    strings = {name: np.asarray(pairs[name].to_pylist(), dtype=object)[keep] for name in _PAIR_COLUMNS}
    source = np.asarray(boxes_table["source"].to_pylist(), dtype=object)[box_row[keep]]

    if len(set(strings["scene_token"].tolist())) != 1:
        raise DataFormatError(pairs_path, "a shard's pairs must all be of one scene", field="scene_token")
    records = scene_records(db, str(strings["scene_token"][0]), settings.sweeps)
    found: list[dict[str, Any]] = []
    samples = list(dict.fromkeys(strings["sample_token"].tolist()))  # first-appearance order
    for sample_token in samples:
        members = np.flatnonzero(strings["sample_token"] == sample_token)
        position = records.position(sample_token)
        frames_a = [_camera_frame(records, position, c) for c in strings["camera_a"][members]]
        frames_b = [_camera_frame(records, position, c) for c in strings["camera_b"][members]]
        geometry = pair_geometry(boxes_a[keep[members]], boxes_b[keep[members]], np.stack([f[0] for f in frames_a]),
                                 np.stack([f[0] for f in frames_b]), np.stack([f[1] for f in frames_a]),
                                 np.stack([f[1] for f in frames_b]), settings.max_distance)
        if not geometry.overlap.any():
            continue
        points_global, point_extra = lidar_points_global(db, records, position)
        for k in np.flatnonzero(geometry.overlap):
            i = members[k]  # index among the kept pairs
            inside, union = pair_union(points_global, geometry, k, np.stack([boxes_a[keep[i]], boxes_b[keep[i]]]),
                                       (frames_a[k][1], frames_b[k][1]), settings.min_depth, settings.max_depth)
            if not inside.any():
                continue
            to_ref = geometry.to_ref[k]
            points_ref = points_global[inside] @ to_ref[:3, :3].T + to_ref[:3, 3]
            labels = points_in_boxes(points_ref, center_cam[i:i + 1], size[i:i + 1], rotation[i:i + 1])[0]
            if not labels.any():
                continue
            angle = float(geometry.angle[k])
            found.append({"pair": i, "angle": angle, "points": union, "intensity": point_extra[inside, 0],
                          "labels": labels.astype(np.int8),
                          "center_frustum": rotate_to_frustum(center_cam[i:i + 1], angle)[0],
                          "heading_frustum": heading_cam[i] - angle})
    found.sort(key=lambda item: item["pair"])
    return _union_table(found, strings, source, score, center_cam, size, rotation, heading_cam)


def _union_table(found: list[dict[str, Any]], strings: dict[str, np.ndarray], source: np.ndarray, score: np.ndarray,
                 center_cam: np.ndarray, size: np.ndarray, rotation: np.ndarray, heading_cam: np.ndarray) -> pa.Table:
    """The rows of the union frustums ``found`` (pair index into the kept pairs' arrays)."""
    if not found:
        return UNION_SCHEMA.empty_table()
    pair = np.array([item["pair"] for item in found], dtype=np.int64)
    counts = np.array([len(item["labels"]) for item in found], dtype=np.int64)
    offsets = pa.array(np.concatenate([[0], np.cumsum(counts)]).astype(np.int32))
    points = np.concatenate([item["points"] for item in found])

    def ragged(values: np.ndarray, kind: pa.DataType) -> pa.Array:
        return pa.ListArray.from_arrays(offsets, pa.array(values, kind))

    def vectors(values: np.ndarray) -> pa.Array:
        return pa.array(values.astype(np.float32).tolist(), pa.list_(pa.float32()))

    columns = {
        "detection_id": strings["reference_detection_id"][pair].tolist(),
        "scene_token": strings["scene_token"][pair].tolist(),
        "sample_token": strings["sample_token"][pair].tolist(),
        "camera": strings["camera_a"][pair].tolist(),
        "positive_detection_id": strings["positive_detection_id"][pair].tolist(),
        "camera_b": strings["camera_b"][pair].tolist(),
        "class": strings["class"][pair].tolist(),
        "score": pa.array(score[pair], pa.float32()),
        "source": source[pair].tolist(),
        "instance_token": strings["instance_token"][pair].tolist(),
        "rot_angle": pa.array([item["angle"] for item in found], pa.float32()),
        "num_points": pa.array(counts.astype(np.int32)),
        "x": ragged(points[:, 0].astype(np.float32), pa.float32()),
        "y": ragged(points[:, 1].astype(np.float32), pa.float32()),
        "z": ragged(points[:, 2].astype(np.float32), pa.float32()),
        "intensity": ragged(np.concatenate([item["intensity"] for item in found]).astype(np.float32), pa.float32()),
        "label": ragged(np.concatenate([item["labels"] for item in found]), pa.int8()),
        "box_center_cam": vectors(center_cam[pair]),
        "box_size": vectors(size[pair]),
        "box_rotation_cam": vectors(rotation[pair]),
        "box_heading_cam": pa.array(heading_cam[pair], pa.float32()),
        "box_center_frustum": vectors(np.stack([item["center_frustum"] for item in found])),
        "box_heading_frustum": pa.array([item["heading_frustum"] for item in found], pa.float32()),
    }
    return pa.table(columns, schema=UNION_SCHEMA)


def stored_key(path: Path) -> str | None:
    """The key in a union file's metadata; None when the file is missing or unreadable."""
    try:
        metadata = pq.read_schema(path).metadata or {}
    except (OSError, pa.ArrowInvalid):
        return None
    value = metadata.get(KEY_FIELD)
    return None if value is None else value.decode()


def build_union_shards(cache: str | Path, folder: str | Path, selection: FrustumSelection,
                       settings: MultiviewSettings, progress: Progress = SILENT) -> dict[str, int]:
    """Write ``folder/<shard>.parquet``, the union frustums of each cache shard (module docstring).

    A shard whose file already holds this key is not recomputed (a resumed run). The dataroot
    must be the cache's dataset (its tables' fingerprint), checked even when every shard is
    reused, so a resume cannot record another one; its tables are loaded only when a shard
    needs computing.

    Returns:
        {shard file name: union frustums in its file}, in shard order.
    """
    from sianms_cli.nuscenes.fingerprint import dataset_fingerprint
    from sianms_cli.nuscenes.loader import NuScenesDB, version_folder

    if dataset_fingerprint(version_folder(settings.dataroot, settings.version)) != settings.dataset_sha256:
        raise SianmsError(f"--dataroot {settings.dataroot}: not the dataset the cache {cache} was "
                          "prepared from (its tables' fingerprint differs)")
    folder = Path(folder)
    paths = frustum_shards(cache)
    records = shard_records(Path(cache))
    db = None
    counts: dict[str, int] = {}
    progress.start(len(paths), "shard", "multiview frustums")
    for path in paths:
        target = folder / path.name
        key = shard_key(cache, path.stem, selection, settings, records)
        if stored_key(target) != key:
            if db is None:
                db = NuScenesDB(settings.dataroot, settings.version)
            table = union_frustums(db, cache, path.stem, selection, settings)
            table = table.replace_schema_metadata({**(table.schema.metadata or {}), KEY_FIELD: key.encode()})
            with atomic_file(target) as stream:
                pq.write_table(table, stream, compression="zstd")
        counts[path.name] = pq.read_metadata(target).num_rows
        progress.advance()
    return counts
