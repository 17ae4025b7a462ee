"""Ground truth, split order, ego poses and racks as the devkit's loaders produce them."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from metrics_reference import reference_script
from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.metrics.boxes import ATTRIBUTE, DETECTION_NAMES, NO_ATTRIBUTE
from sianms_cli.metrics.dataset import bicycle_racks, ego_poses, eval_split, ground_truth
from sianms_cli.nuscenes.classes import CATEGORY_TO_DETECTION
from sianms_cli.nuscenes.loader import NuScenesDB


def box_velocity(db, token: str, max_time_diff: float = 1.5) -> np.ndarray:
    """The devkit's NuScenes.box_velocity, line by line."""
    current = db.get("sample_annotation", token)
    has_prev, has_next = current["prev"] != "", current["next"] != ""
    if not has_prev and not has_next:
        return np.array([np.nan, np.nan, np.nan])
    first = db.get("sample_annotation", current["prev"]) if has_prev else current
    last = db.get("sample_annotation", current["next"]) if has_next else current
    pos_diff = np.array(last["translation"]) - np.array(first["translation"])
    time_last = 1e-6 * db.get("sample", last["sample_token"])["timestamp"]
    time_first = 1e-6 * db.get("sample", first["sample_token"])["timestamp"]
    time_diff = time_last - time_first
    if has_next and has_prev:
        max_time_diff *= 2
    if time_diff > max_time_diff:
        return np.array([np.nan, np.nan, np.nan])
    return pos_diff / time_diff


def test_split_order_is_the_sample_table_order(reference_db):
    custom = eval_split(reference_db, "custom_all")  # splits.json lists scene-0103 first
    assert not custom.predefined
    assert list(custom.sample_tokens) == reference_db.table("sample").tokens.tolist()
    mini_val = eval_split(reference_db, "mini_val")
    assert mini_val.predefined and len(mini_val) == len(eval_split(reference_db, "custom_val"))
    scenes = reference_db.table("scene")
    names = scenes.column("name")[reference_db.table("sample").rows("scene_token")[mini_val.sample_rows]]
    assert set(names.tolist()) == {"scene-0103"}


def test_split_errors(reference_db):
    with pytest.raises(SianmsError, match="needs a dataset version ending in 'trainval'"):
        eval_split(reference_db, "val")
    with pytest.raises(SianmsError, match="no split 'nope'"):
        eval_split(reference_db, "nope")


def test_a_custom_split_of_unknown_scenes_names_its_file_and_split(reference_folder, tmp_path):
    dataroot = shutil.copytree(reference_folder / "dataroot", tmp_path / "dataroot")
    splits = dataroot / reference_script.VERSION / "splits.json"
    splits.write_text(json.dumps({"ghost": ["scene-9999", "scene-9998"]}))
    db = NuScenesDB(dataroot, reference_script.VERSION)
    with pytest.raises(DataFormatError) as error:
        eval_split(db, "ghost")
    assert str(error.value) == (f"{splits}: field 'ghost': none of the split's 2 scenes has a sample in "
                                f"{db.table_root / 'scene.json'}")


def test_ground_truth_matches_the_devkits_loader(reference_db):
    split = eval_split(reference_db, "custom_all")
    boxes, rows = ground_truth(reference_db, split)
    annotations = reference_db.table("sample_annotation")
    expected_rows = []
    for index, token in enumerate(split.sample_tokens):  # the devkit: sample['anns'] of each sample
        for row in reference_db.sample_annotation_rows(token):
            record = reference_db.get("sample_annotation", str(annotations.tokens[row]))
            if record["category_name"] in CATEGORY_TO_DETECTION:
                expected_rows.append((index, row, record))
    assert rows.tolist() == [row for _, row, _ in expected_rows]
    for box, (index, _, record) in zip(boxes, expected_rows):
        assert box["sample"] == index
        assert DETECTION_NAMES[box["label"]] == CATEGORY_TO_DETECTION[record["category_name"]]
        assert box["num_pts"] == record["num_lidar_pts"] + record["num_radar_pts"]
        assert box["translation"].tolist() == record["translation"]
        attribute_tokens = record["attribute_tokens"]
        expected_attribute = (ATTRIBUTE[reference_db.get("attribute", attribute_tokens[0])["name"]]
                              if attribute_tokens else NO_ATTRIBUTE)
        assert box["attribute"] == expected_attribute
        expected_velocity = box_velocity(reference_db, record["token"])[:2]
        assert np.array_equal(box["velocity"], expected_velocity, equal_nan=True)
    assert (boxes["attribute"] == NO_ATTRIBUTE).any()


def test_velocity_is_nan_for_a_lone_annotation_or_a_long_gap(reference_folder, tmp_path):
    root = tmp_path / "dataroot"
    shutil.copytree(reference_folder / "dataroot", root)
    tables = root / reference_script.VERSION
    annotations = json.loads((tables / "sample_annotation.json").read_text())
    annotations[0]["prev"] = annotations[0]["next"] = ""  # now a lone annotation
    (tables / "sample_annotation.json").write_text(json.dumps(annotations))
    samples = json.loads((tables / "sample.json").read_text())
    samples[5]["timestamp"] += 10_000_000  # 10 s gaps around sample 5
    (tables / "sample.json").write_text(json.dumps(samples))
    db = NuScenesDB(root, reference_script.VERSION)
    split = eval_split(db, "custom_all")
    boxes, rows = ground_truth(db, split)
    tokens = db.table("sample_annotation").tokens
    expected = np.array([box_velocity(db, str(tokens[row]))[:2] for row in rows])
    assert np.array_equal(boxes["velocity"], expected, equal_nan=True)
    assert (rows == 0).sum() == 1 and np.isnan(boxes["velocity"][rows == 0]).all()
    assert np.isnan(boxes["velocity"]).all(axis=1).sum() > 1


def test_ego_poses_are_those_of_the_lidar_key_frames(reference_db):
    split = eval_split(reference_db, "mini_val")
    rotation, translation = ego_poses(reference_db, split)
    for i, token in enumerate(split.sample_tokens):
        lidar_token = reference_db.keyframe_data(token)["LIDAR_TOP"]
        expected_rotation, expected_translation = reference_db.ego_pose_of(lidar_token)
        assert np.array_equal(rotation[i], expected_rotation) and np.array_equal(translation[i], expected_translation)


def test_bicycle_racks_of_the_split(reference_db):
    split = eval_split(reference_db, "custom_all")
    racks = bicycle_racks(reference_db, split)
    assert len(racks) > 0
    assert np.all(racks["size"] == reference_script.RACK_SIZE)
    assert np.all(np.diff(racks["sample"]) >= 0)
