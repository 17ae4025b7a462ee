"""Frustum PointNets training batches streamed from a prepared cache's ``frustums/`` shards.

One shard (a scene) is in memory at a time, so memory stays flat in the cache's size. Each
kept frustum gives (docs/methods.md#frustums):

- ``points`` (N, C): N points drawn uniformly with replacement from the frustum's points,
  every time it is read; xyz in the frustum frame and the intensity divided by 255;
- ``seg`` (N,): the cached per-point label (1 inside the associated box);
- ``center`` (3,), ``heading``: the box in the frustum frame (F-PointNets heading);
- ``lwh`` (3,): the box size as **(l, w, h)**. The cache stores nuScenes' (w, l, h); this is
  the one place the order is converted;
- ``class_index``: the position of the cache's ``class`` in ``classes`` (also the size cluster).

Kept frustums: the class is one of ``classes``, there is an associated box, at least one point
is inside it, and the 2-D box is at least ``min_box_height`` pixels high. A "cyclist" is
nuScenes' ``bicycle``; the cache has no rider attribute, so a parked bicycle counts too. Union
frustums (``--multiview``, :mod:`sianms_cli.data.multiview`) are appended to their shard's
single ones and flagged ``union``. Augmentation (training only, on whole batches): random flip,
random depth shift, and a turn of the frustum axis standing in for the original's 2-D box
jitter (docs/methods.md#frustum-augmentation).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Iterator

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from sianms_cli.data.cache import PREPARE_AGAIN, read_shard_table, require_finite, verified_shard, verified_shards
from sianms_cli.errors import DataFormatError
from sianms_cli.nuscenes.classes import PAPER_CLASSES
from sianms_cli.nuscenes.loader import MAX_BOX_SIZE

INTENSITY_SCALE = 255.0
FRUSTUM_COLUMNS = ["detection_id", "class", "score", "source", "rot_angle", "x", "y", "z", "intensity", "label",
                   "box_size", "box_center_frustum", "box_heading_frustum"]
NUMERIC_FRUSTUM_COLUMNS = ["score", "rot_angle", "x", "y", "z", "intensity", "box_size", "box_center_frustum",
                           "box_heading_frustum"]


@dataclass(frozen=True)
class FrustumSelection:
    """Which frustums a dataset keeps and how each one is sampled.

    Attributes:
        classes: cache class names, in one-hot order.
        num_points: points drawn per frustum (1,024 as the original; fewer for CPU runs).
        min_box_height: minimum 2-D box height, pixels (25 as the original; 0 keeps all).
        intensity: keep the intensity channel (4 channels; 3 without).
    """

    classes: tuple[str, ...] = PAPER_CLASSES
    num_points: int = 1024
    min_box_height: float = 25.0
    intensity: bool = True


@dataclass(frozen=True)
class Augmentation:
    """The training augmentation switches (module docstring)."""

    flip: bool = True
    shift: bool = True
    jitter: bool = True


@dataclass(frozen=True, eq=False)
class ShardFrustums:
    """The kept frustums of one shard, points concatenated (rows ``offsets[i]:offsets[i + 1]``).

    Attributes:
        offsets: (F + 1,) int64.
        points: (M, C) float32, xyz (+ intensity / 255).
        labels: (M,) int64.
        center: (F, 3), heading: (F,), lwh: (F, 3) (l, w, h), float64, frustum frame.
        class_index: (F,) int64; score: (F,) float32 (the 2-D detector's); rot_angle: (F,).
        detection_id: (F,) object array of the cache's ids (a union's: its reference detection's).
        union: (F,) bool, a union frustum of a camera pair (``multiview``), not a single camera's.
    """

    offsets: np.ndarray
    points: np.ndarray
    labels: np.ndarray
    center: np.ndarray
    heading: np.ndarray
    lwh: np.ndarray
    class_index: np.ndarray
    score: np.ndarray
    rot_angle: np.ndarray
    detection_id: np.ndarray
    union: np.ndarray

    def __len__(self) -> int:
        return len(self.class_index)


def frustum_shards(cache: str | Path) -> list[Path]:
    """The ``frustums/`` files of a cache, in shard-name order, checked against its manifest."""
    return verified_shards(cache, "frustums")


def _box_heights(frustums_path: Path, detection_id: pa.ChunkedArray) -> np.ndarray:
    """(F,) 2-D box height (pixels, y2 - y1) of each detection, from the shard's detections file.

    Looked up by id, keeping the frustums' row order (a hash join would not promise it).
    """
    path = verified_shard(frustums_path.parent.parent, "detections", frustums_path.stem)
    table = read_shard_table(path, columns=["detection_id", "y1", "y2"])
    where = pc.index_in(detection_id, value_set=table["detection_id"].combine_chunks())
    if where.null_count:
        raise DataFormatError(path, "a frustum's detection is missing from the detections file", field="detection_id")
    height = table["y2"].to_numpy() - table["y1"].to_numpy()
    return height[where.to_numpy()]


def read_shard(path: Path, selection: FrustumSelection) -> ShardFrustums:
    """The kept frustums of one shard file (module docstring), converted to F-PointNets' conventions."""
    table = read_shard_table(path, columns=FRUSTUM_COLUMNS)
    require_finite(path, table, NUMERIC_FRUSTUM_COLUMNS)
    require_frustum_shapes(path, table)
    if selection.min_box_height > 0:
        table = table.filter(pa.array(_box_heights(path, table["detection_id"]) >= selection.min_box_height))
    return frustums_of_table(table, selection)


def read_union_shard(path: Path, selection: FrustumSelection) -> ShardFrustums:
    """The kept union frustums of one shard (:mod:`sianms_cli.data.multiview`), as :func:`read_shard`'s.

    The file was built for the run's classes and minimum box height (both 2-D boxes of a pair);
    the same class, box and object-point filters apply again here. Rows are flagged ``union``.
    """
    return frustums_of_table(pq.read_table(path, columns=FRUSTUM_COLUMNS), selection, union=True)


def require_frustum_shapes(path: Path, table: pa.Table) -> None:
    """Raise DataFormatError naming the first record (``detection_id``) and field of a frustums table
    that breaks what prepare writes: a point list of another length than ``x``'s, a label other than
    0 or 1, a box centre or size without its 3 values, a size not in (0, MAX_BOX_SIZE] m. An edited
    cache had ended in a traceback deep in training, or a size of 1e30 as "training diverged"."""
    def fail(rows: np.ndarray, field: str, problem: str) -> None:
        if len(rows):
            raise DataFormatError(path, f"{problem}; {PREPARE_AGAIN}", token=str(table["detection_id"][int(rows[0])]),
                                  field=field)

    def lengths(name: str) -> np.ndarray:
        return pc.list_value_length(table[name]).fill_null(-1).to_numpy(zero_copy_only=False)

    require_point_lists(path, table)
    labels = table["label"].combine_chunks()
    wrong = ~np.isin(pc.list_flatten(labels).to_numpy(zero_copy_only=False), (0, 1))
    fail(pc.list_parent_indices(labels).to_numpy()[wrong], "label", "expected 0 or 1 per point")
    has_box = table["box_center_frustum"].is_valid().to_numpy(zero_copy_only=False)
    for name in ("box_center_frustum", "box_size"):
        fail(np.flatnonzero(has_box & (lengths(name) != 3)), name, "expected 3 values for the box")
    sizes = table["box_size"].combine_chunks()
    bad = pc.list_flatten(sizes).to_numpy(zero_copy_only=False)
    bad = (bad <= 0) | (bad > MAX_BOX_SIZE)
    fail(pc.list_parent_indices(sizes).to_numpy()[bad], "box_size", f"expected sizes in (0, {MAX_BOX_SIZE:g}] m")


POINT_COLUMNS = ("x", "y", "z", "intensity", "label")
"""The per-point list columns of a frustums file: one value per point each."""


def require_point_lists(path: Path, table: pa.Table) -> None:
    """Raise DataFormatError naming the first record (``detection_id``) and field of a frustums table whose
    point lists (:data:`POINT_COLUMNS`, those the table has besides ``x``) are out of step with ``x``'s:
    every reader of frustums checks it (an edited file had been a traceback in `sianms eval`)."""
    points = pc.list_value_length(table["x"]).fill_null(-1).to_numpy(zero_copy_only=False)
    for name in POINT_COLUMNS[1:]:
        if name in table.column_names:
            wrong = np.flatnonzero(pc.list_value_length(table[name]).fill_null(-1).to_numpy(zero_copy_only=False)
                                   != points)
            if len(wrong):
                raise DataFormatError(path, f"not one value per point of x; {PREPARE_AGAIN}",
                                      token=str(table["detection_id"][int(wrong[0])]), field=name)


def frustums_of_table(table: pa.Table, selection: FrustumSelection, union: bool = False) -> ShardFrustums:
    """The frustums of a table of :data:`FRUSTUM_COLUMNS` that have a class of ``selection``, a box
    and an object point, converted to F-PointNets' conventions (module docstring)."""
    table = table.filter(pc.and_(pc.is_in(table["class"], pa.array(list(selection.classes))),
                                 pc.is_valid(table["box_center_frustum"])))
    has_points = pc.list_value_length(table["label"]).to_numpy(zero_copy_only=False) > 0
    object_points = np.zeros(len(table), dtype=np.int64)
    if has_points.any():
        parent = pc.list_parent_indices(table["label"]).to_numpy()
        np.add.at(object_points, parent, pc.list_flatten(table["label"]).to_numpy().astype(np.int64))
    table = table.filter(pa.array(object_points > 0))
    counts = pc.list_value_length(table["x"]).to_numpy(zero_copy_only=False).astype(np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    channels = ["x", "y", "z"] + (["intensity"] if selection.intensity else [])
    points = np.stack([pc.list_flatten(table[c]).to_numpy() for c in channels], axis=1).astype(np.float32)
    if selection.intensity:
        points[:, 3] /= INTENSITY_SCALE
    wlh = _fixed(table["box_size"], 3)
    return ShardFrustums(
        offsets=offsets,
        points=points.reshape(-1, len(channels)),
        labels=pc.list_flatten(table["label"]).to_numpy().astype(np.int64),
        center=_fixed(table["box_center_frustum"], 3),
        heading=table["box_heading_frustum"].to_numpy().astype(np.float64),
        lwh=wlh[:, [1, 0, 2]],  # nuScenes (w, l, h) -> F-PointNets (l, w, h): the one conversion
        class_index=np.array([selection.classes.index(c) for c in table["class"].to_pylist()], dtype=np.int64),
        score=table["score"].to_numpy().astype(np.float32),
        rot_angle=table["rot_angle"].to_numpy().astype(np.float64),
        detection_id=np.array(table["detection_id"].to_pylist(), dtype=object),
        union=np.full(len(table), union),
    )


def concatenate_shards(parts: list[ShardFrustums]) -> ShardFrustums:
    """The frustums of several :class:`ShardFrustums` one after the other (at least one part)."""
    if len(parts) == 1:
        return parts[0]
    counts = np.concatenate([np.diff(part.offsets) for part in parts])
    joined = {field.name: np.concatenate([getattr(part, field.name) for part in parts])
              for field in fields(ShardFrustums) if field.name != "offsets"}
    return ShardFrustums(offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64), **joined)


def _fixed(column: pa.ChunkedArray, width: int) -> np.ndarray:
    """(F, width) float64 from a list column whose rows all hold ``width`` values."""
    return pc.list_flatten(column).to_numpy().astype(np.float64).reshape(-1, width)


def class_statistics(cache: str | Path, selection: FrustumSelection) -> tuple[np.ndarray, np.ndarray]:
    """(counts (K,), mean (l, w, h) (K, 3)) of the kept frustums per class, one shard at a time.

    The means are the size clusters (one per class, as the original's per-type clusters). A
    class with no frustum gets NaN; the caller decides (training refuses it).
    """
    k = len(selection.classes)
    counts, sums = np.zeros(k, dtype=np.int64), np.zeros((k, 3))
    for path in frustum_shards(cache):
        shard = read_shard(path, selection)
        counts += np.bincount(shard.class_index, minlength=k)
        np.add.at(sums, shard.class_index, shard.lwh)
    with np.errstate(invalid="ignore", divide="ignore"):
        return counts, sums / counts[:, None]


def sample_points(shard: ShardFrustums, rows: np.ndarray, num_points: int,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(points (B, N, C), seg (B, N)): N points drawn with replacement from each frustum ``rows``."""
    start = shard.offsets[rows]
    count = shard.offsets[rows + 1] - start
    index = start[:, None] + np.floor(rng.random((len(rows), num_points)) * count[:, None]).astype(np.int64)
    return shard.points[index], shard.labels[index]


def augment(batch: dict[str, np.ndarray], rng: np.random.Generator, augmentation: Augmentation) -> None:
    """Apply the training augmentation to a batch, in place (docs/methods.md#frustum-augmentation).

    - jitter: the frustum frame turns about y by a uniform angle within ±10 % of the frustum's
      half-width angle (max |x/z| of its points), as a ±10 % shift of the 2-D box centre would
      move the centre ray; the heading turns with it;
    - flip, p = 0.5: x -> -x for points and centre, heading -> π - heading;
    - shift: z += s for points and centre, s = clip(N(0, 1) · 0.05 · d, ±0.2 d), d the box's
      horizontal distance (the original's evident intent; its code clips to [0.8 d, 1.2 d]).
    """
    points, center, heading = batch["points"], batch["center"], batch["heading"]
    size = len(center)
    if augmentation.jitter:
        half_width = np.abs(points[..., 0] / np.maximum(points[..., 2], 1e-3)).max(axis=1)
        angle = rng.uniform(-0.1, 0.1, size) * np.arctan(half_width)
        _rotate_about_y(points, center, angle)
        heading -= angle
    if augmentation.flip:
        flip = rng.random(size) < 0.5
        points[flip, :, 0] *= -1
        center[flip, 0] *= -1
        heading[flip] = np.pi - heading[flip]
    if augmentation.shift:
        distance = np.hypot(center[:, 0], center[:, 2])
        shift = np.clip(rng.standard_normal(size) * 0.05 * distance, -0.2 * distance, 0.2 * distance)
        points[..., 2] += shift[:, None].astype(points.dtype)
        center[:, 2] += shift


def _rotate_about_y(points: np.ndarray, center: np.ndarray, angle: np.ndarray) -> None:
    """Rotate points (B, N, ≥3) and centres (B, 3) as ``rotate_to_frustum`` does, by a per-row angle."""
    cos, sin = np.cos(angle), np.sin(angle)
    x, z = points[..., 0].copy(), points[..., 2].copy()
    points[..., 0] = cos[:, None] * x - sin[:, None] * z
    points[..., 2] = sin[:, None] * x + cos[:, None] * z
    cx, cz = center[:, 0].copy(), center[:, 2].copy()
    center[:, 0] = cos * cx - sin * cz
    center[:, 2] = sin * cx + cos * cz


def iterate_batches(cache: str | Path, selection: FrustumSelection, batch_size: int, rng: np.random.Generator,
                    train: bool, augmentation: Augmentation = Augmentation(),
                    unions: str | Path | None = None,
                    shards: np.ndarray | None = None) -> Iterator[dict[str, np.ndarray]]:
    """Batches of frustums, one shard in memory at a time.

    Training: shards and the frustums of each shard in random order, augmented; a final
    partial batch is kept unless it holds a single frustum (batch norm needs two).
    Evaluation: cache order, no augmentation, every frustum.

    ``shards``: the indices of the shards to read, in order (a stream's,
    :mod:`sianms_cli.data.streams`); None: every shard, in a random order when training.

    ``unions``: a folder of union-frustum shards (:func:`sianms_cli.data.multiview.build_union_shards`),
    one per cache shard under the same name; each shard's union frustums join its single ones
    (after them, before the shuffle), so they are sampled, batched and augmented alike.

    Yields dicts of ``points`` (B, N, C) float32, ``seg`` (B, N), ``center`` (B, 3),
    ``heading`` (B,), ``lwh`` (B, 3), ``class_index`` (B,), ``score`` (B,), ``rot_angle`` (B,),
    ``detection_id`` (B,), ``union`` (B,) bool.
    """
    paths = frustum_shards(cache)
    if shards is None and train:
        shards = rng.permutation(len(paths))
    if shards is not None:
        paths = [paths[i] for i in shards]
    pending: list[dict[str, np.ndarray]] = []
    waiting = 0
    for path in paths:
        shard = read_shard(path, selection)
        if unions is not None:
            union_path = Path(unions) / path.name
            if not union_path.is_file():
                raise DataFormatError(union_path, f"missing: no union frustums for cache shard {path.name}")
            shard = concatenate_shards([shard, read_union_shard(union_path, selection)])
        order = rng.permutation(len(shard)) if train else np.arange(len(shard))
        for start in range(0, len(order), batch_size):
            rows = order[start:start + batch_size]
            points, seg = sample_points(shard, rows, selection.num_points, rng)
            pending.append({"points": points, "seg": seg, "center": shard.center[rows].copy(),
                            "heading": shard.heading[rows].copy(), "lwh": shard.lwh[rows],
                            "class_index": shard.class_index[rows], "score": shard.score[rows],
                            "rot_angle": shard.rot_angle[rows], "detection_id": shard.detection_id[rows],
                            "union": shard.union[rows]})
            waiting += len(rows)
            while waiting >= batch_size:
                batch, pending, waiting = _take(pending, batch_size)
                yield _finish(batch, rng, train, augmentation)
    if waiting >= (2 if train else 1):
        batch, _, _ = _take(pending, waiting)
        yield _finish(batch, rng, train, augmentation)


def concatenate_batches(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The frustums of several batches one after the other (at least one part)."""
    if len(parts) == 1:
        return parts[0]
    return {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}


def empty_batch(selection: FrustumSelection) -> dict[str, np.ndarray]:
    """A batch of no frustums, with :func:`iterate_batches`'s keys, dtypes and trailing shapes."""
    channels = 4 if selection.intensity else 3
    return {"points": np.zeros((0, selection.num_points, channels), dtype=np.float32),
            "seg": np.zeros((0, selection.num_points), dtype=np.int64), "center": np.zeros((0, 3)),
            "heading": np.zeros(0), "lwh": np.zeros((0, 3)), "class_index": np.zeros(0, dtype=np.int64),
            "score": np.zeros(0, dtype=np.float32), "rot_angle": np.zeros(0),
            "detection_id": np.zeros(0, dtype=object), "union": np.zeros(0, dtype=bool)}


def _take(pending: list[dict[str, np.ndarray]], size: int) -> tuple[dict[str, np.ndarray], list, int]:
    """The first ``size`` frustums of the pending pieces, and what is left."""
    joined = concatenate_batches(pending)
    batch = {key: value[:size] for key, value in joined.items()}
    rest = {key: value[size:] for key, value in joined.items()}
    left = len(rest["center"])
    return batch, ([rest] if left else []), left


def _finish(batch: dict[str, np.ndarray], rng: np.random.Generator, train: bool,
            augmentation: Augmentation) -> dict[str, np.ndarray]:
    """The batch as yielded: augmented when training (after batching, so one call per batch)."""
    if train:
        augment(batch, rng, augmentation)
    return batch
