"""THE overlap rule on a dataset's boxes: the rig of each box's sample, its LIDAR_TOP ego pose."""

import json
import shutil

import numpy as np
import pytest

from sianms_cli.geometry.transforms import apply_transform, invert_transform, make_transform
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.overlap import OverlapBits, box_overlap_pairs, centers_in_ego, lidar_ego_poses
from sianms_cli.nuscenes.sample_rigs import sample_rigs

VERSION = "v1.0-mini"


@pytest.fixture(scope="module")
def dataroot(synthetic_dataroot):
    return synthetic_dataroot()


def reference_bits(db, sample_tokens, box_sample, centers):
    """Sample by sample with the loader's look-ups, as `info` did before."""
    rigs, rig_of_sample = sample_rigs(db, sample_tokens)
    names = list(dict.fromkeys(name for rig in rigs for name in rig.pair_names))
    bits = np.zeros(len(centers), dtype=np.uint64)
    for s, token in enumerate(sample_tokens):
        data = db.keyframe_data(token)
        rows = np.flatnonzero(box_sample == s)
        if rig_of_sample[s] < 0 or "LIDAR_TOP" not in data or len(rows) == 0:
            continue
        pose = make_transform(*db.ego_pose_of(data["LIDAR_TOP"]))
        rig = rigs[rig_of_sample[s]]
        seen = rig.overlap_pairs(apply_transform(invert_transform(pose), centers[rows]))
        for column, name in enumerate(rig.pair_names):
            bits[rows[seen[:, column]]] |= np.uint64(1 << names.index(name))
    return tuple(names), bits


def test_box_overlap_pairs_equal_the_sample_by_sample_rule(dataroot):
    db = NuScenesDB(dataroot, VERSION)
    annotations = db.table("sample_annotation")
    samples = db.table("sample").tokens.tolist()
    box_sample, centers = annotations.rows("sample_token"), annotations.column("translation")
    overlap = box_overlap_pairs(db, samples, box_sample, centers)
    names, bits = reference_bits(db, samples, box_sample, centers)
    assert overlap.pair_names == names and len(names) == 6
    assert np.array_equal(overlap.bits, bits) and 0 < np.count_nonzero(bits) < len(bits)
    # Samples in another order, boxes of a subset: the same bits for the same boxes.
    order = np.arange(len(samples))[::-1]
    some = np.flatnonzero(box_sample % 2 == 0)
    again = box_overlap_pairs(db, [samples[i] for i in order], np.argsort(order)[box_sample[some]], centers[some])
    assert np.array_equal(again.bits, bits[some])


def test_centers_in_ego_are_the_lidar_key_frames_ego_frame(dataroot):
    db = NuScenesDB(dataroot, VERSION)
    samples = db.table("sample").tokens.tolist()
    rotation, translation, found = lidar_ego_poses(db, np.arange(len(samples)))
    assert found.all()
    centers = np.random.default_rng(0).normal(0, 30, (50, 3))
    box_sample = np.arange(50) % len(samples)
    got = centers_in_ego(centers, box_sample, rotation, translation)
    for n in range(50):
        pose = make_transform(*db.ego_pose_of(db.keyframe_data(samples[box_sample[n]])["LIDAR_TOP"]))
        np.testing.assert_allclose(got[n], apply_transform(invert_transform(pose), centers[n:n + 1])[0], atol=1e-9)


def test_a_sample_without_lidar_key_frame_has_no_overlap(dataroot, tmp_path):
    (tmp_path / VERSION).mkdir()
    for table in (dataroot / VERSION).glob("*.json"):
        shutil.copy(table, tmp_path / VERSION / table.name)
    db = NuScenesDB(tmp_path, VERSION)
    samples = db.table("sample").tokens.tolist()
    annotations = db.table("sample_annotation")
    box_sample, centers = annotations.rows("sample_token"), annotations.column("translation")
    before = box_overlap_pairs(db, samples, box_sample, centers).bits
    hidden = int(box_sample[np.flatnonzero(before)[0]])  # a sample with boxes in the overlap
    lidar = db.keyframe_data(samples[hidden])["LIDAR_TOP"]
    path = tmp_path / VERSION / "sample_data.json"
    records = json.loads(path.read_text())
    next(r for r in records if r["token"] == lidar)["is_key_frame"] = False
    path.write_text(json.dumps(records))
    db = NuScenesDB(tmp_path, VERSION)
    after = box_overlap_pairs(db, samples, box_sample, centers).bits
    assert (after[box_sample == hidden] == 0).all()
    assert np.array_equal(after[box_sample != hidden], before[box_sample != hidden])
    assert not lidar_ego_poses(db, np.array([hidden]))[2][0]


def test_overlap_bits_as_named_pairs():
    overlap = OverlapBits(("A|B", "B|C", "C|A"), np.array([0b000, 0b101, 0b010], dtype=np.uint64))
    assert overlap.pairs(["C|A", "A|B", "X|Y"]).tolist() == [[False, False, False], [True, True, False],
                                                              [False, False, False]]
    assert overlap.pairs(["B|C"]).tolist() == [[False], [False], [True]]
    assert overlap.pairs([]).shape == (3, 0)


def test_a_dataroot_without_any_camera_key_frame_has_no_overlap(dataroot, tmp_path):
    """A LiDAR-only (or partly downloaded) dataroot had ended `info`, `prepare`, `metrics` and `eval` in an
    IndexError: the mask over the cameras' key frames was one long over none."""
    (tmp_path / VERSION).mkdir()
    for table in (dataroot / VERSION).glob("*.json"):
        shutil.copy(table, tmp_path / VERSION / table.name)
    path = tmp_path / VERSION / "sample_data.json"
    records = json.loads(path.read_text())
    for record in records:
        if "/CAM_" in record["filename"]:
            record["is_key_frame"] = False
    path.write_text(json.dumps(records))
    db = NuScenesDB(tmp_path, VERSION)
    samples = db.table("sample").tokens.tolist()
    rigs, rig_of_sample = sample_rigs(db, samples)
    assert rigs == [] and (rig_of_sample == -1).all()
    annotations = db.table("sample_annotation")
    bits = box_overlap_pairs(db, samples, annotations.rows("sample_token"), annotations.column("translation")).bits
    assert len(bits) == len(annotations) and (bits == 0).all()
