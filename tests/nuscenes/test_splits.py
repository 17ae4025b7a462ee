import json
import re

import pytest

from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.splits import (
    PREDEFINED_SPLITS,
    load_split_file,
    split_sample_tokens,
    split_scene_names,
    splits_for_version,
)

VERSION = "v1.0-mini"


def test_predefined_split_sizes_match_the_devkit():
    splits = {**splits_for_version("v1.0-trainval"), **splits_for_version("v1.0-mini"),
              **splits_for_version("v1.0-test")}
    assert set(splits) == set(PREDEFINED_SPLITS)
    assert {name: len(scenes) for name, scenes in splits.items()} == {
        "train": 700, "val": 150, "test": 150, "mini_train": 8, "mini_val": 2,
        "train_detect": 350, "train_track": 350,
    }
    for scenes in splits.values():
        assert len(set(scenes)) == len(scenes)
    assert splits["train"] == sorted(set(splits["train_detect"]) | set(splits["train_track"]))
    everything = splits["train"] + splits["val"] + splits["test"]
    assert len(set(everything)) == 1000
    assert all(re.fullmatch(r"scene-\d{4}", name) for name in everything)
    assert splits["mini_val"] == ["scene-0103", "scene-0916"]
    assert splits["mini_train"] == ["scene-0061", "scene-0553", "scene-0655", "scene-0757",
                                    "scene-0796", "scene-1077", "scene-1094", "scene-1100"]
    # As in the devkit, two mini_train scenes are val scenes of the full dataset.
    assert set(splits["mini_train"]) & set(splits["val"]) == {"scene-0553", "scene-0796"}
    assert {"scene-0001", "scene-0002"} <= set(splits["train_detect"])
    assert splits["val"][:3] == ["scene-0003", "scene-0012", "scene-0013"]


def test_splits_for_version_follow_the_suffix():
    assert list(splits_for_version("v1.0-mini")) == ["mini_train", "mini_val"]
    assert list(splits_for_version("v1.0-trainval")) == ["train", "val", "train_detect",
                                                         "train_track"]
    assert list(splits_for_version("v1.0-test")) == ["test"]
    assert splits_for_version("synthetic") == {}


@pytest.mark.parametrize("split, version, suffix", [
    ("val", "v1.0-mini", "trainval"), ("train_track", "v1.0-test", "trainval"),
    ("mini_val", "v1.0-trainval", "mini"), ("test", "v1.0-trainval", "test"),
])
def test_predefined_split_needs_a_matching_version(split, version, suffix):
    with pytest.raises(SianmsError) as caught:
        split_scene_names(split, version)
    assert str(caught.value) == (
        f"split '{split}' needs a dataset version ending in '{suffix}', got '{version}'")


def test_predefined_split_returns_a_fresh_list():
    names = split_scene_names("mini_val", VERSION)
    names.append("scene-9999")
    assert split_scene_names("mini_val", VERSION) == ["scene-0103", "scene-0916"]
    assert len(split_scene_names("test", "v1.0-test")) == 150


def test_custom_split_without_a_dataroot():
    with pytest.raises(SianmsError) as caught:
        split_scene_names("night", VERSION)
    assert str(caught.value) == (
        "split 'night' is not predefined (for v1.0-mini: mini_train, mini_val); custom splits "
        "are read from <dataroot>/<version>/splits.json, which needs a dataroot")


def test_custom_split_without_a_splits_file(tmp_path):
    (tmp_path / VERSION).mkdir()
    with pytest.raises(DataFormatError) as caught:
        split_scene_names("night", VERSION, tmp_path)
    assert str(caught.value) == (
        f"{tmp_path / VERSION / 'splits.json'}: not found; split 'night' is not predefined "
        "(for v1.0-mini: mini_train, mini_val), so it must be defined in this file")


def test_custom_split_from_splits_json(tmp_path):
    (tmp_path / VERSION).mkdir()
    path = tmp_path / VERSION / "splits.json"
    path.write_text(json.dumps({"night": ["scene-0916"], "rain": []}))
    assert split_scene_names("night", VERSION, tmp_path) == ["scene-0916"]
    assert split_scene_names("rain", VERSION, tmp_path) == []
    with pytest.raises(SianmsError) as caught:
        split_scene_names("fog", VERSION, tmp_path)
    assert str(caught.value) == (
        f"{path}: no split 'fog'; available: night, rain (predefined for v1.0-mini: "
        "mini_train, mini_val)")


def test_predefined_names_win_over_splits_json(tmp_path):
    (tmp_path / VERSION).mkdir()
    (tmp_path / VERSION / "splits.json").write_text(json.dumps({"mini_val": ["scene-0001"]}))
    assert split_scene_names("mini_val", VERSION, tmp_path) == ["scene-0103", "scene-0916"]


@pytest.mark.parametrize("content, message", [
    ('{"a": ["scene-1"],\n "b": [}', "invalid JSON at line 2, column"),
    ('["scene-1"]', "top level must be an object mapping split names to lists of scene names, got list"),
    ('{"a": "scene-1"}', "field 'a': expected a list of scene names"),
    ('{"a": ["scene-1", 2]}', "field 'a': expected a list of scene names"),
    ('{"a": ["scene-1", "scene-2", "scene-1"]}', "field 'a': scene 'scene-1' is listed twice"),
])
def test_user_split_file_is_validated(tmp_path, content, message):
    path = tmp_path / "my_splits.json"
    path.write_text(content)
    with pytest.raises(DataFormatError) as caught:
        load_split_file(path)
    assert str(caught.value).startswith(f"{path}: {message}")


def test_user_split_file(tmp_path):
    path = tmp_path / "my_splits.json"
    path.write_text(json.dumps({"day": ["scene-0103"], "night": ["scene-0916", "scene-0061"]}))
    assert load_split_file(path) == {"day": ["scene-0103"], "night": ["scene-0916", "scene-0061"]}
    with pytest.raises(DataFormatError, match="split file not found"):
        load_split_file(tmp_path / "absent.json")


def test_split_sample_tokens(tiny_dataroot, tiny_records):
    db = NuScenesDB(tiny_dataroot, VERSION)
    samples = [r["token"] for r in tiny_records["sample"]]
    assert split_sample_tokens(db, "mini_val") == samples
    # mini_train scenes are not in the tiny dataset: skipped, as the devkit does.
    assert split_sample_tokens(db, "mini_train") == []
    (tiny_dataroot / VERSION / "splits.json").write_text(
        json.dumps({"second": ["scene-0916", "scene-0001"]}))
    assert split_sample_tokens(db, "second") == samples[3:]
    with pytest.raises(SianmsError, match="needs a dataset version ending in 'trainval'"):
        split_sample_tokens(db, "val")
