"""data/frustum_dataset.py on a hand-made cache: filters, the (w, l, h) -> (l, w, h) conversion,
sampling within each frustum, streaming (union frustums beside their shard's single ones), and
augmentation that keeps points and boxes consistent."""

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from cache_records import record_again

from sianms_cli.data.frustum_dataset import (
    Augmentation,
    FrustumSelection,
    augment,
    class_statistics,
    iterate_batches,
    read_shard,
    read_union_shard,
    sample_points,
)
from sianms_cli.data.schemas import FRUSTUMS_SCHEMA
from sianms_cli.errors import DataFormatError


def inside_box(points, center, lwh, heading):
    """(B, N) bool: F-PointNets convention (length axis (cos h, 0, -sin h), height along y)."""
    offset = points[..., :3] - center[:, None, :]
    c, s = np.cos(heading)[:, None], np.sin(heading)[:, None]
    along = offset[..., 0] * c - offset[..., 2] * s
    across = offset[..., 0] * s + offset[..., 2] * c
    return ((np.abs(along) <= lwh[:, None, 0] / 2) & (np.abs(across) <= lwh[:, None, 1] / 2)
            & (np.abs(offset[..., 1]) <= lwh[:, None, 2] / 2))


def frustum_row(rng, ident, cls, wlh, height_px, box=True, points=40, object_fraction=0.5, tag=0.0):
    """One frustum row: points spread around a box at 15 m, labelled by the box; intensity = tag."""
    center = np.array([rng.uniform(-1, 1), 0.5, 15.0])
    heading = rng.uniform(-np.pi, np.pi)
    lwh = np.array([wlh[1], wlh[0], wlh[2]])
    near = int(points * object_fraction)
    xyz = np.concatenate([center + rng.uniform(-0.3, 0.3, (near, 3)) * lwh,
                          center + rng.uniform(3, 6, (points - near, 3))])
    labels = inside_box(xyz[None], center[None], lwh[None], np.array([heading]))[0]
    row = {"detection_id": ident, "scene_token": "s", "sample_token": "t", "sample_data_token": "d",
           "camera": "CAM_FRONT", "class": cls, "score": 0.9, "source": "detector", "instance_token": "i",
           "rot_angle": 0.1, "num_points": points, "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2],
           "intensity": np.full(points, tag), "time_lag": np.zeros(points), "label": labels.astype(np.int8),
           "box_center_cam": None, "box_size": list(wlh), "box_rotation_cam": None, "box_heading_cam": heading + 0.1,
           "box_center_frustum": list(center), "box_heading_frustum": heading}
    if not box:
        row.update(box_size=None, box_center_frustum=None, box_heading_frustum=None, instance_token=None)
    return row, {"detection_id": ident, "y1": 10.0, "y2": 10.0 + height_px}


def write_cache(root, shards):
    (root / "frustums").mkdir(parents=True)
    (root / "detections").mkdir()
    for name, rows in shards.items():
        frustums = [r for r, _ in rows]
        columns = {f.name: [r[f.name] for r in frustums] for f in FRUSTUMS_SCHEMA}
        pq.write_table(pa.table(columns, schema=FRUSTUMS_SCHEMA), root / "frustums" / f"{name}.parquet")
        pq.write_table(pa.Table.from_pylist([d for _, d in rows]), root / "detections" / f"{name}.parquet")
    return record_again(root)


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    rng = np.random.default_rng(0)
    first = [
        frustum_row(rng, "a", "car", (2.0, 5.0, 1.5), 30, tag=25.5),  # kept
        frustum_row(rng, "b", "car", (1.8, 4.0, 1.6), 10, tag=51.0),  # too low for 25 px
        frustum_row(rng, "c", "pedestrian", (0.6, 0.7, 1.8), 40, box=False),  # no box
        frustum_row(rng, "d", "truck", (2.5, 9.0, 3.0), 60),  # class not asked for
        frustum_row(rng, "e", "bicycle", (0.6, 1.7, 1.3), 40, object_fraction=0.0),  # no object point
        frustum_row(rng, "f", "pedestrian", (0.6, 0.8, 1.7), 50, points=7, tag=76.5),  # kept
    ]
    second = [frustum_row(rng, f"g{i}", ("car", "pedestrian")[i % 2], (1.9, 4.5, 1.6), 80, points=20 + i,
                          tag=float(100 + i)) for i in range(9)]
    return write_cache(tmp_path_factory.mktemp("cache"), {"scene-1": first, "scene-2": second})


def test_filters_and_the_one_size_conversion(cache):
    shard = read_shard(cache / "frustums" / "scene-1.parquet", FrustumSelection(min_box_height=25))
    assert shard.detection_id.tolist() == ["a", "f"]
    assert shard.lwh[0].tolist() == [5.0, 2.0, 1.5]  # (w, l, h) in the cache -> (l, w, h)
    assert shard.class_index.tolist() == [0, 1]
    assert shard.points.shape == (47, 4)
    assert np.allclose(shard.points[:40, 3], 0.1) and np.allclose(shard.points[40:, 3], 0.3)  # intensity / 255
    loose = read_shard(cache / "frustums" / "scene-1.parquet", FrustumSelection(min_box_height=0, intensity=False))
    assert loose.detection_id.tolist() == ["a", "b", "f"] and loose.points.shape[1] == 3
    with_truck = read_shard(cache / "frustums" / "scene-1.parquet",
                            FrustumSelection(classes=("car", "truck"), min_box_height=0))
    assert with_truck.detection_id.tolist() == ["a", "b", "d"]


def test_class_statistics_stream_every_shard(cache):
    counts, means = class_statistics(cache, FrustumSelection(min_box_height=25))
    assert counts.tolist() == [1 + 5, 1 + 4, 0]
    assert means[0] == pytest.approx([(5.0 + 5 * 4.5) / 6, (2.0 + 5 * 1.9) / 6, (1.5 + 5 * 1.6) / 6])
    assert np.isnan(means[2]).all()


def test_points_are_drawn_from_their_own_frustum_with_their_labels(cache):
    shard = read_shard(cache / "frustums" / "scene-2.parquet", FrustumSelection())
    rows = np.array([3, 0, 8])
    points, seg = sample_points(shard, rows, 50, np.random.default_rng(1))
    assert points.shape == (3, 50, 4) and seg.shape == (3, 50)
    assert np.allclose(points[..., 3], (100 + rows)[:, None] / 255)  # the intensity tags each frustum
    assert (seg == inside_box(points, shard.center[rows], shard.lwh[rows], shard.heading[rows])).all()


def test_evaluation_streams_every_kept_frustum_once_in_order(cache):
    selection = FrustumSelection(num_points=16)
    batches = list(iterate_batches(cache, selection, 4, np.random.default_rng(0), train=False))
    assert [len(b["center"]) for b in batches] == [4, 4, 3]
    ids = np.concatenate([b["detection_id"] for b in batches]).tolist()
    assert ids == ["a", "f"] + [f"g{i}" for i in range(9)]


def test_training_order_is_seeded_and_drops_only_a_lone_last_frustum(cache):
    selection = FrustumSelection(num_points=16)
    first = list(iterate_batches(cache, selection, 5, np.random.default_rng(3), train=True))
    again = list(iterate_batches(cache, selection, 5, np.random.default_rng(3), train=True))
    assert [len(b["center"]) for b in first] == [5, 5]  # 11 frustums: the 11th alone is dropped
    for a, b in zip(first, again):
        assert (a["detection_id"] == b["detection_id"]).all() and np.array_equal(a["points"], b["points"])


def test_augmentation_keeps_points_and_boxes_consistent(cache):
    shard = read_shard(cache / "frustums" / "scene-2.parquet", FrustumSelection())
    rows = np.arange(len(shard))
    points, seg = sample_points(shard, rows, 64, np.random.default_rng(2))
    batch = {"points": points, "seg": seg, "center": shard.center.copy(), "heading": shard.heading.copy(),
             "lwh": shard.lwh}
    before = {key: value.copy() for key, value in batch.items()}
    augment(batch, np.random.default_rng(5), Augmentation())
    assert not np.allclose(batch["points"], before["points"])
    assert (inside_box(batch["points"], batch["center"], batch["lwh"], batch["heading"]) == seg).all()
    flipped = np.sign(batch["center"][:, 0]) != np.sign(before["center"][:, 0])
    assert flipped.any() and (~flipped).any()  # p = 0.5 over 9 frustums
    untouched = dict(before)
    augment(untouched, np.random.default_rng(5), Augmentation(flip=False, shift=False, jitter=False))
    assert np.array_equal(untouched["points"], before["points"])


@pytest.fixture(scope="module")
def unions(cache, tmp_path_factory):
    """Union frustums beside the hand-made cache (as data/multiview.py writes them): two in
    scene-1 (one with no object point, dropped), none in scene-2."""
    rng = np.random.default_rng(7)
    rows = [frustum_row(rng, "u1", "car", (1.9, 4.4, 1.5), 30, points=12, tag=127.5)[0],
            frustum_row(rng, "u2", "pedestrian", (0.6, 0.7, 1.8), 30, points=5)[0],
            frustum_row(rng, "u3", "car", (1.9, 4.4, 1.5), 30, object_fraction=0.0)[0]]
    folder = tmp_path_factory.mktemp("unions")
    columns = {f.name: [r[f.name] for r in rows] for f in FRUSTUMS_SCHEMA}
    pq.write_table(pa.table(columns, schema=FRUSTUMS_SCHEMA), folder / "scene-1.parquet")
    pq.write_table(FRUSTUMS_SCHEMA.empty_table(), folder / "scene-2.parquet")
    return folder


def test_union_frustums_join_their_shard_flagged(cache, unions):
    selection = FrustumSelection(num_points=16)
    batches = list(iterate_batches(cache, selection, 4, np.random.default_rng(0), train=False, unions=unions))
    ids = np.concatenate([b["detection_id"] for b in batches]).tolist()
    assert ids == ["a", "f", "u1", "u2"] + [f"g{i}" for i in range(9)]  # after their shard's singles
    assert np.concatenate([b["union"] for b in batches]).tolist() == [False] * 2 + [True] * 2 + [False] * 9
    union = read_union_shard(unions / "scene-1.parquet", selection)
    assert union.union.all() and union.lwh[0].tolist() == pytest.approx([4.4, 1.9, 1.5])
    assert np.allclose(union.points[:12, 3], 0.5)  # intensity / 255, as the singles
    assert len(read_shard(cache / "frustums" / "scene-1.parquet", selection)) == 2  # the singles unchanged


def test_union_frustums_are_trained_in_the_same_shuffled_batches(cache, unions):
    selection = FrustumSelection(num_points=16)
    first = list(iterate_batches(cache, selection, 5, np.random.default_rng(3), train=True, unions=unions))
    again = list(iterate_batches(cache, selection, 5, np.random.default_rng(3), train=True, unions=unions))
    assert [len(b["center"]) for b in first] == [5, 5, 3]  # 13 frustums
    assert sum(int(b["union"].sum()) for b in first) == 2
    assert any(b["union"].any() and not b["union"].all() for b in first)  # mixed with single frustums
    for a, b in zip(first, again):
        assert (a["detection_id"] == b["detection_id"]).all() and np.array_equal(a["points"], b["points"])


def test_a_missing_union_shard_is_a_format_error(cache, tmp_path):
    with pytest.raises(DataFormatError, match="union frustums"):
        list(iterate_batches(cache, FrustumSelection(), 4, np.random.default_rng(0), train=False, unions=tmp_path))


@pytest.mark.parametrize("field, value", [("rot_angle", np.nan), ("z", np.inf), ("box_center_frustum", np.nan)])
def test_a_number_that_is_not_finite_names_its_file_record_and_field(tmp_path, field, value):
    """A NaN in a cache a user edited or damaged: one error at the read, not a NaN loss (or a NaN
    box blamed on another file) later. A frustum without a box (nulls) is fine."""
    rng = np.random.default_rng(1)
    rows = [frustum_row(rng, "ok", "car", (2.0, 5.0, 1.5), 30),
            frustum_row(rng, "nobox", "car", (2.0, 5.0, 1.5), 30, box=False),
            frustum_row(rng, "bad", "car", (2.0, 5.0, 1.5), 30)]
    bad = rows[2][0]
    if isinstance(bad[field], (list, np.ndarray)):
        bad[field] = np.asarray(bad[field], dtype=float)
        bad[field][-1] = value
    else:
        bad[field] = value
    root = write_cache(tmp_path / "cache", {"scene-1": rows})
    path = root / "frustums" / "scene-1.parquet"
    with pytest.raises(DataFormatError, match=rf"^{path}: record bad: field '{field}': not a finite number"):
        read_shard(path, FrustumSelection())


@pytest.mark.parametrize("field, edit, problem", [
    ("x", lambda row: row.update(x=row["x"][:-1]), None),  # then y is the one out of step
    ("label", lambda row: row.update(label=row["label"][:-1]), "not one value per point of x"),
    ("label", lambda row: row["label"].__setitem__(0, 5), "expected 0 or 1 per point"),
    ("label", lambda row: row["label"].__setitem__(0, -1), "expected 0 or 1 per point"),
    ("box_center_frustum", lambda row: row.update(box_center_frustum=[1.0, 2.0]), "expected 3 values for the box"),
    ("box_size", lambda row: row.update(box_size=None), "expected 3 values for the box"),
    ("box_size", lambda row: row.update(box_size=[2.0, 0.0, 1.5]), "expected sizes in (0, 1000] m"),
    ("box_size", lambda row: row.update(box_size=[2.0, 1e30, 1.5]), "expected sizes in (0, 1000] m"),
])
def test_a_frustum_prepare_could_not_have_written_names_its_file_record_and_field(tmp_path, field, edit, problem):
    """Each had ended in a traceback deep in training (a shape, an index out of bounds), or as
    "training diverged" (a size of 1e30)."""
    rng = np.random.default_rng(1)
    rows = [frustum_row(rng, "ok", "car", (2.0, 5.0, 1.5), 30), frustum_row(rng, "bad", "car", (2.0, 5.0, 1.5), 30)]
    edit(rows[1][0])
    root = write_cache(tmp_path / "cache", {"scene-1": rows})
    path = root / "frustums" / "scene-1.parquet"
    named = "y" if field == "x" else field
    message = problem or "not one value per point of x"
    with pytest.raises(DataFormatError) as raised:
        read_shard(path, FrustumSelection())
    assert str(raised.value) == (f"{path}: record bad: field '{named}': {message}; rerun `sianms prepare` on the "
                                 "cache to rebuild it")
