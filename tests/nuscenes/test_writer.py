import hashlib
import json
import subprocess

import numpy as np
import pytest
from devkit_venv import DEVKIT_PYTHON, REPO_ROOT, needs_devkit
from PIL import Image

from sianms_cli.errors import OutputExistsError
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.tables import SENSORS, TABLE_NAMES
from sianms_cli.nuscenes.writer import (
    DatasetWriter,
    attribute_token,
    category_token,
    checked_record,
    make_token,
)

VERSION = "v1.0-mini"
LOG = {"token": "log1", "logfile": "n008-2018-08-01-15-16-36-0400", "vehicle": "n008",
       "date_captured": "2018-08-01", "location": "boston-seaport"}
POSE = {"token": "pose1", "timestamp": 1533151603547590, "rotation": [1.0, 0.0, 0.0, 0.0],
        "translation": [411.3, 1180.9, 0.0]}


def test_make_token_is_md5_of_the_parts_as_a_json_list():
    assert make_token("sample", "scene-0103", 2) == hashlib.md5(
        b'["sample", "scene-0103", "2"]').hexdigest()
    assert make_token("a/b", "c") != make_token("a", "b/c")
    assert make_token(3) == make_token("3")
    assert len(make_token("x")) == 32 and int(make_token("x"), 16) >= 0
    with pytest.raises(ValueError):
        make_token()


def test_vocabulary_tokens_are_derived_from_names():
    assert category_token("vehicle.car") == make_token("category", "vehicle.car")
    assert attribute_token("cycle.with_rider") == make_token("attribute", "cycle.with_rider")
    with pytest.raises(ValueError, match="unknown category 'vehicle.spaceship'"):
        category_token("vehicle.spaceship")
    with pytest.raises(ValueError, match="unknown attribute"):
        attribute_token("vehicle.flying")


def test_records_are_written_one_per_line_in_schema_order(tmp_path):
    with DatasetWriter(tmp_path, VERSION) as writer:
        writer.add("log", dict(reversed(list(LOG.items()))))
        writer.add("log", {**LOG, "token": "log2"})
    text = (tmp_path / VERSION / "log.json").read_text()
    first = json.dumps(LOG)
    second = json.dumps({**LOG, "token": "log2"})
    assert text == f"[\n{first},\n{second}\n]\n"
    assert (tmp_path / VERSION / "scene.json").read_text() == "[]\n"
    assert sorted(p.name for p in (tmp_path / VERSION).iterdir()) == sorted(
        f"{name}.json" for name in TABLE_NAMES)


def test_numpy_values_are_written_as_plain_json(tmp_path):
    record = {"token": np.str_("pose1"), "timestamp": np.int64(1533151603547590),
              "rotation": np.array([1.0, 0.0, 0.0, 0.0]), "translation": (411.3, 1180.9, 0.0)}
    assert checked_record("ego_pose", record) == POSE


@pytest.mark.parametrize("table, record, message", [
    ("logs", LOG, "unknown table 'logs'"),
    ("log", {**LOG, "colour": "red"}, "log record log1: field 'colour': not in the log schema"),
    ("log", {k: v for k, v in LOG.items() if k != "vehicle"}, "log record log1: field 'vehicle': missing"),
    ("ego_pose", {**POSE, "timestamp": "1533151603547590"},
     "ego_pose record pose1: field 'timestamp': expected an integer, got '1533151603547590' (str)"),
    ("ego_pose", {**POSE, "translation": [1.0, 2.0]},
     "ego_pose record pose1: field 'translation': expected a list of 3 finite numbers"),
    ("ego_pose", {**POSE, "translation": np.array([1.0, np.nan, 0.0])},
     "ego_pose record pose1: field 'translation': expected a list of 3 finite numbers"),
    ("ego_pose", {k: v for k, v in POSE.items() if k != "token"},
     "ego_pose record <no token>: field 'token': missing"),
])
def test_add_refuses_records_that_break_the_schema(tmp_path, table, record, message):
    writer = DatasetWriter(tmp_path, VERSION)
    with pytest.raises(ValueError) as caught:
        writer.add(table, record)
    assert str(caught.value).startswith(message)
    writer.abort()


def test_same_records_give_byte_identical_files(tmp_path, tiny_records, write_dataset):
    write_dataset(tmp_path / "a", tiny_records)
    write_dataset(tmp_path / "b", tiny_records)
    for name in (f"{t}.json" for t in TABLE_NAMES):
        assert (tmp_path / "a" / VERSION / name).read_bytes() == (
            tmp_path / "b" / VERSION / name).read_bytes()
    maps = sorted((tmp_path / "a" / "maps").iterdir())
    assert [p.read_bytes() for p in maps] == [
        (tmp_path / "b" / "maps" / p.name).read_bytes() for p in maps]


def test_tables_stay_partial_until_close(tmp_path):
    writer = DatasetWriter(tmp_path, VERSION)
    writer.add("log", LOG)
    assert [p.name.startswith(".log.json.") and p.suffix == ".partial"
            for p in (tmp_path / VERSION).iterdir()] == [True]
    assert not (tmp_path / VERSION / "log.json").exists()
    assert writer.count("log") == 1 and writer.count("scene") == 0
    writer.close()
    assert not list((tmp_path / VERSION).glob(".*.partial"))
    with pytest.raises(ValueError, match="writer is closed"):
        writer.add("log", LOG)


def test_an_exception_inside_the_writer_leaves_no_table(tmp_path):
    with pytest.raises(RuntimeError):
        with DatasetWriter(tmp_path, VERSION) as writer:
            writer.add("log", LOG)
            raise RuntimeError("generator failed")
    assert list((tmp_path / VERSION).iterdir()) == []


def test_finished_tables_are_not_overwritten_unless_asked(tmp_path):
    with DatasetWriter(tmp_path, VERSION) as writer:
        writer.add("log", LOG)
    with pytest.raises(OutputExistsError, match="already holds finished tables"):
        DatasetWriter(tmp_path, VERSION)
    with DatasetWriter(tmp_path, VERSION, overwrite=True) as writer:
        writer.add("log", {**LOG, "token": "log9"})
    assert json.loads((tmp_path / VERSION / "log.json").read_text())[0]["token"] == "log9"


def test_static_tables_load_back(tmp_path):
    with DatasetWriter(tmp_path, VERSION) as writer:
        writer.add_static_tables()
    db = NuScenesDB(tmp_path, VERSION)
    assert [len(db.table(t)) for t in ("category", "attribute", "visibility", "sensor")] == [
        23, 8, 4, 12]
    car = db.table("category").index(category_token("vehicle.car"))
    assert db.table("category").record(car)["name"] == "vehicle.car"
    assert db.table("sensor").tokens.tolist() == [s.token for s in SENSORS]
    assert db.table("visibility").record(3) == {
        "description": "visibility of whole object is between 80 and 100%", "token": "4",
        "level": "v80-100"}


def test_add_map_writes_a_png_raster_and_the_record(tmp_path):
    with DatasetWriter(tmp_path, VERSION) as writer:
        writer.add("log", LOG)
        writer.add_map("map1", ["log1"])
    with Image.open(tmp_path / "maps" / "map1.png") as raster:
        assert raster.format == "PNG" and raster.size == (8, 8)
    assert json.loads((tmp_path / VERSION / "map.json").read_text()) == [
        {"category": "semantic_prior", "token": "map1", "filename": "maps/map1.png",
         "log_tokens": ["log1"]}]


def test_write_splits(tmp_path):
    writer = DatasetWriter(tmp_path, VERSION)
    writer.write_splits({"my_val": ("scene-0916",), "empty": []})
    assert json.loads((tmp_path / VERSION / "splits.json").read_text()) == {
        "my_val": ["scene-0916"], "empty": []}
    with pytest.raises(ValueError, match="'bad' must map a name to a list of scene names"):
        writer.write_splits({"bad": "scene-0916"})
    writer.abort()


@pytest.mark.devkit
@needs_devkit
def test_the_official_devkit_loads_and_evaluates_the_written_dataset(tmp_path, tiny_dataroot):
    out = tmp_path / "dump.json"
    done = subprocess.run([str(DEVKIT_PYTHON), str(REPO_ROOT / "scripts" / "devkit_dump.py"),
                           str(tiny_dataroot), VERSION, str(out), "--split", "mini_val"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    dump = json.loads(out.read_text())
    db = NuScenesDB(tiny_dataroot, VERSION)
    assert dump["table_counts"] == {name: len(db.table(name)) for name in TABLE_NAMES}
    assert dump["evaluation"]["n_samples"] == len(db.table("sample"))
    camera_data = {(c["sample_token"], c["channel"]): c["sample_data_token"] for c in dump["cameras"]}
    assert camera_data == {(sample, "CAM_FRONT"): db.keyframe_data(sample)["CAM_FRONT"]
                           for sample in db.table("sample").tokens.tolist()}
