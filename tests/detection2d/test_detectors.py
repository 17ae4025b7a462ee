"""The Detector protocol and the one place a --detector value becomes a detector."""

import json

import numpy as np
import pytest

from sianms_cli.detection2d.detections import GroundTruth2D
from sianms_cli.detection2d.detectors import DetectorSpec, build_detector, parse_detector
from sianms_cli.detection2d.external import ExternalDetections
from sianms_cli.detection2d.simulated import SimulatedDetector, SimulatedDetectorConfig, simulate_detections
from sianms_cli.errors import SianmsError
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.prepare.config import PrepareConfig

SIZE = (160, 90)


@pytest.fixture(scope="module")
def db(synthetic_dataroot):
    return NuScenesDB(synthetic_dataroot(), "v1.0-mini")


def two_cars():
    boxes = np.array([[10.0, 30, 50, 60], [90, 20, 150, 70]])
    return GroundTruth2D(np.arange(2), boxes, np.array(["car", "car"]), np.zeros(2), np.zeros(2), np.full(2, 15.0))


def test_parse_detector():
    assert parse_detector("simulated") == DetectorSpec()
    assert parse_detector("file:dets/a b.json").file.as_posix() == "dets/a b.json"
    for bad in ("yolo", "file:", "Simulated", "", "simulated "):
        with pytest.raises(SianmsError, match="--detector") as caught:
            parse_detector(bad)
        assert f"unknown detector '{bad}'" in str(caught.value)


def test_the_config_validates_with_the_same_parser(db):
    with pytest.raises(SianmsError, match="unknown detector 'file:'.*--detector"):
        PrepareConfig(str(db.dataroot), "v1.0-mini", "mini_train", detector="file:")


def test_the_simulated_detector_draws_from_the_generator_it_is_given(db):
    detector = build_detector("simulated", db, ("car", "pedestrian"))
    assert isinstance(detector, SimulatedDetector)
    gt = two_cars()
    got = detector.detections("any-token", gt, SIZE, np.random.default_rng(3))
    expected = simulate_detections(gt, SIZE, np.random.default_rng(3), SimulatedDetectorConfig(("car", "pedestrian")))
    assert np.array_equal(got.boxes, expected.boxes) and np.array_equal(got.scores, expected.scores)
    assert got.classes.tolist() == expected.classes.tolist()


def test_the_file_detector_looks_images_up_by_token(db, tmp_path):
    cameras = db.table("sample_data").tokens[db.sample_data_modalities() == "camera"]
    front, other = str(cameras[0]), str(cameras[1])
    rows = [{"sample_data_token": front, "x1": 1.0, "y1": 2.0, "x2": 30.0, "y2": 40.0, "score": 0.4, "class": "car"},
            {"sample_data_token": front, "x1": 5.0, "y1": 5.0, "x2": 9.0, "y2": 9.0, "score": 0.9, "class": "car"},
            {"sample_data_token": front, "x1": 0.0, "y1": 0.0, "x2": 5.0, "y2": 5.0, "score": 0.8, "class": "bus"}]
    path = tmp_path / "dets.json"
    path.write_text(json.dumps(rows))
    detector = build_detector(f"file:{path}", db, ("car",))
    assert isinstance(detector, ExternalDetections)
    got = detector.detections(front, two_cars(), SIZE, np.random.default_rng(0))
    assert got.scores.tolist() == [0.9, 0.4] and got.classes.tolist() == ["car", "car"]  # by score; bus not asked
    assert got.boxes.tolist() == [[5.0, 5.0, 9.0, 9.0], [1.0, 2.0, 30.0, 40.0]]
    assert len(detector.detections(other, two_cars(), SIZE, np.random.default_rng(0))) == 0


def test_a_coordinate_no_float_can_hold_names_its_row_and_field(db, tmp_path):
    """x1 = 10**400 (JSON allows any number of digits) had ended in an OverflowError traceback."""
    from sianms_cli.errors import DataFormatError

    token = str(db.table("sample_data").tokens[db.sample_data_modalities() == "camera"][0])
    row = {"sample_data_token": token, "x1": 1.0, "y1": 2.0, "x2": 30.0, "y2": 40.0, "score": 0.4, "class": "car"}
    path = tmp_path / "dets.json"
    path.write_text(json.dumps([row, {**row, "x1": 10**400}]))
    with pytest.raises(DataFormatError) as caught:
        build_detector(f"file:{path}", db, ("car",))
    assert str(caught.value) == f"{path}: field 'x1': row 1: expected a number a float can hold"
