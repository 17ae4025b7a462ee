"""Evaluation regions: names, and membership by THE overlap rule of each sample's rig."""

from __future__ import annotations

import numpy as np
import pytest

from sianms_cli.errors import SianmsError
from sianms_cli.metrics.dataset import ego_poses, eval_split, ground_truth
from sianms_cli.metrics.regions import centers_in_ego, overlap_bits, region_mask, resolve_regions
from sianms_cli.geometry.transforms import apply_transform, invert_transform, make_transform
from sianms_cli.nuscenes.overlap import box_overlap_pairs
from sianms_cli.nuscenes.sample_rigs import sample_rigs

PAIRS = ("CAM_FRONT|CAM_FRONT_RIGHT", "CAM_FRONT_RIGHT|CAM_BACK_RIGHT", "CAM_BACK_RIGHT|CAM_BACK",
         "CAM_BACK|CAM_BACK_LEFT", "CAM_BACK_LEFT|CAM_FRONT_LEFT", "CAM_FRONT_LEFT|CAM_FRONT")


def test_resolve_regions():
    assert resolve_regions(["all", " overlap", "all"], PAIRS) == ["all", "overlap"]
    assert resolve_regions(["overlap:CAM_FRONT_RIGHT|CAM_FRONT"], PAIRS) == ["overlap:CAM_FRONT|CAM_FRONT_RIGHT"]
    assert resolve_regions(["non-overlap", "overlap:*"], PAIRS) == ["non-overlap"] + [f"overlap:{p}" for p in PAIRS]
    for bad in ("overlaps", "overlap:CAM_FRONT|CAM_BACK", "overlap:CAM_FRONT", "overlap:CAM_FRONT|CAM_FRONT"):
        with pytest.raises(SianmsError, match="unknown region") as caught:
            resolve_regions([bad], PAIRS)
        assert "overlap:CAM_FRONT|CAM_FRONT_RIGHT" in str(caught.value)
    with pytest.raises(SianmsError, match="no region"):
        resolve_regions([], PAIRS)


def test_overlap_bits_follow_each_samples_rig(reference_db):
    split = eval_split(reference_db, "custom_all")
    boxes, _ = ground_truth(reference_db, split)
    rotation, translation = ego_poses(reference_db, split)
    centers = centers_in_ego(boxes, rotation, translation)
    rigs, rig_of_sample = sample_rigs(reference_db, split.sample_tokens)
    assert len(rigs) == 2 and set(rig_of_sample.tolist()) == {0, 1}  # one calibration per scene
    overlap = overlap_bits(boxes, centers, rigs, rig_of_sample)
    assert overlap.pair_names == PAIRS
    for i, box in enumerate(boxes[:300]):
        token = split.sample_tokens[box["sample"]]
        pose = reference_db.ego_pose_of(reference_db.keyframe_data(token)["LIDAR_TOP"])
        center = apply_transform(invert_transform(make_transform(*pose)), box["translation"][None])
        np.testing.assert_allclose(centers[i], center[0], atol=1e-9)
        rig = rigs[rig_of_sample[box["sample"]]]
        seen = rig.overlap_pairs(center)[0]
        expected = sum(1 << PAIRS.index(name) for name, hit in zip(rig.pair_names, seen) if hit)
        assert int(overlap.bits[i]) == expected
    in_overlap = region_mask("overlap", overlap, len(boxes))
    assert 0 < in_overlap.sum() < len(boxes)
    assert np.array_equal(region_mask("non-overlap", overlap, len(boxes)), ~in_overlap)
    union = np.zeros(len(boxes), dtype=bool)
    for pair in PAIRS:
        union |= region_mask(f"overlap:{pair}", overlap, len(boxes))
    assert np.array_equal(union, in_overlap)
    assert region_mask("all", None, len(boxes)).all()


def test_the_evaluations_overlap_is_the_datasets_one_rule(reference_db):
    # What `sianms metrics` computes from its box tables is what prepare and info get from
    # nuscenes/overlap.py for the same annotations (two scenes, two rigs).
    split = eval_split(reference_db, "custom_all")
    boxes, _ = ground_truth(reference_db, split)
    rotation, translation = ego_poses(reference_db, split)
    rigs, rig_of_sample = sample_rigs(reference_db, split.sample_tokens)
    metrics = overlap_bits(boxes, centers_in_ego(boxes, rotation, translation), rigs, rig_of_sample)
    dataset = box_overlap_pairs(reference_db, split.sample_tokens, boxes["sample"], boxes["translation"])
    assert metrics.pair_names == dataset.pair_names == PAIRS
    assert np.array_equal(metrics.bits, dataset.bits) and np.count_nonzero(dataset.bits) > 0


def test_a_sample_without_cameras_has_no_overlap():
    from sianms_cli.metrics.boxes import make_boxes

    boxes = make_boxes([0, 0], "car", [[5, 0, 0], [10, 0, 0]])
    overlap = overlap_bits(boxes, boxes["translation"], [], np.array([-1]))
    assert overlap.pair_names == () and overlap.bits.tolist() == [0, 0]
