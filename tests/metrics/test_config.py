"""Evaluation configurations: the devkit's preset verbatim, the paper's, user JSON files."""

from __future__ import annotations

import json

import pytest

from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.metrics.config import DETECTION_CVPR_2019, DetectionConfig, load_config


def test_detection_cvpr_2019_is_the_devkits_json():
    config = load_config("detection_cvpr_2019")
    assert config.serialize() == {
        "class_range": {"car": 50, "truck": 50, "bus": 50, "trailer": 50, "construction_vehicle": 50,
                        "pedestrian": 40, "motorcycle": 40, "bicycle": 40, "traffic_cone": 30, "barrier": 30},
        "dist_fcn": "center_distance", "dist_ths": [0.5, 1.0, 2.0, 4.0], "dist_th_tp": 2.0,
        "min_recall": 0.1, "min_precision": 0.1, "max_boxes_per_sample": 500, "mean_ap_weight": 5,
    }
    assert config.class_names[0] == "car" and config.class_names[-1] == "barrier"
    assert config.name == "detection_cvpr_2019"


def test_paper_config():
    config = load_config("paper")
    assert config.class_range == {"car": 50, "pedestrian": 40, "bicycle": 40}
    assert config.dist_ths == (0.5, 1.0, 2.0, 4.0) and config.dist_th_tp == 2.0
    assert config.labels.tolist() == [0, 5, 7]
    ranges = config.range_by_label()
    assert ranges[0] == 50 and ranges[1] == float("-inf")


def test_user_file_takes_missing_fields_from_the_devkit(tmp_path):
    path = tmp_path / "cfg.json"
    path.write_text(json.dumps({"class_range": {"pedestrian": 25, "car": 35.5}, "dist_ths": [1, 3], "dist_th_tp": 3}))
    config = load_config(path)
    assert config.class_names == ("pedestrian", "car")
    assert config.dist_ths == (1, 3) and config.min_recall == 0.1 and config.mean_ap_weight == 5
    assert config.name == str(path)
    assert DetectionConfig.from_dict(config.serialize()) == DetectionConfig.from_dict(config.serialize())


@pytest.mark.parametrize(("content", "field", "message"), [
    ([], None, "must be a JSON object, got a list"),
    (3, None, "must be a JSON object, got a number"),
    (None, None, "must be a JSON object, got null"),
    ({"class_ranges": {}}, "class_ranges", "unknown field"),
    ({"class_range": {}}, "class_range", "non-empty object"),
    ({"class_range": {"cyclist": 40}}, "class_range.cyclist", "unknown detection class"),
    ({"class_range": {"car": -1}}, "class_range.car", "positive number"),
    ({"class_range": {"car": True}}, "class_range.car", "positive number"),
    ({"dist_fcn": "iou"}, "dist_fcn", "only 'center_distance'"),
    ({"dist_ths": []}, "dist_ths", "non-empty list"),
    ({"dist_ths": [1, 1]}, "dist_ths", "distinct"),
    ({"dist_th_tp": 3.0}, "dist_th_tp", "one of dist_ths"),
    ({"min_recall": 1.5}, "min_recall", "[0, 0.99]"),
    ({"min_recall": 1.0}, "min_recall", "[0, 0.99], got 1.0"),  # no recall point left: AP would be NaN
    ({"min_recall": 0.995}, "min_recall", "[0, 0.99], got 0.995"),
    ({"min_precision": 1}, "min_precision", "[0, 1)"),
    ({"max_boxes_per_sample": 0}, "max_boxes_per_sample", "positive integer"),
    ({"mean_ap_weight": "5"}, "mean_ap_weight", "non-negative number"),
    # each of these had ended in an OverflowError traceback
    ({"min_recall": 1e308}, "min_recall", "[0, 0.99], got 1e+308"),
    ({"class_range": {"car": 10**400}}, "class_range.car", "positive number"),
    ({"dist_ths": [1, 10**400]}, "dist_ths", "positive numbers"),
    ({"mean_ap_weight": 10**400}, "mean_ap_weight", "non-negative number"),
    ({"dist_ths": [0.5 + i for i in range(101)]}, "dist_ths", "at most 100 thresholds (the devkit's: 4), got 101"),
])
def test_invalid_user_files_name_the_file_and_field(tmp_path, content, field, message):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(content))
    with pytest.raises(DataFormatError) as caught:
        load_config(path)
    assert caught.value.path == str(path) and caught.value.field == field
    assert message in str(caught.value)


def test_unknown_name_and_invalid_json(tmp_path):
    with pytest.raises(SianmsError, match="neither a preset"):
        load_config("detection_cvpr_2020")
    path = tmp_path / "broken.json"
    path.write_text("{")
    with pytest.raises(DataFormatError, match="invalid JSON"):
        load_config(path)
    assert set(DETECTION_CVPR_2019) == set(load_config().serialize())
