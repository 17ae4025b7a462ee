import math
import re
import warnings

import numpy as np
import pytest

from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.io import read_json
from sianms_cli.nuscenes import loader
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.sample_rigs import sample_rigs
from sianms_cli.nuscenes.sensors import write_jpeg, write_pcd_bin
from sianms_cli.nuscenes.tables import TABLE_NAMES

VERSION = "v1.0-mini"


@pytest.fixture
def db(tiny_dataroot):
    return NuScenesDB(tiny_dataroot, VERSION)


def _load_error(dataroot):
    with pytest.raises(DataFormatError) as caught:
        NuScenesDB(dataroot, VERSION)
    return caught.value


# --------------------------------------------------------------------------- round trip


def test_every_table_and_record_round_trips(db, tiny_records):
    for name in TABLE_NAMES:
        table = db.table(name)
        assert len(table) == len(tiny_records[name]), name
        assert [table.record(i) for i in range(len(table))] == tiny_records[name], name
        assert table.tokens.tolist() == [r["token"] for r in tiny_records[name]]


def test_columns_have_documented_shapes_and_dtypes(db, tiny_records):
    annotations = db.table("sample_annotation")
    assert annotations.column("translation").shape == (6, 3)
    assert annotations.column("translation").dtype == np.float64
    np.testing.assert_array_equal(annotations.column("translation")[1], [22.0, 3.0, 0.9])
    assert annotations.column("num_lidar_pts").tolist() == [40, 30, 20, 40, 30, 40]
    assert annotations.column("num_lidar_pts").dtype == np.int64
    assert annotations.column("prev").tolist() == [
        r["prev"] for r in tiny_records["sample_annotation"]]
    assert annotations.rows("prev").tolist() == [-1, 0, 1, -1, 3, -1]
    assert annotations.rows("next").tolist() == [1, 2, -1, 4, -1, -1]
    assert annotations.rows("visibility_token").tolist() == [3, 3, 3, 2, 2, -1]
    assert annotations.rows("attribute_tokens").tolist() == [[0], [0], [0], [6], [6], [-1]]
    assert annotations.column("attribute_tokens")[5].tolist() == [""]
    sample_data = db.table("sample_data")
    assert sample_data.column("timestamp").dtype == np.int64
    assert sample_data.column("timestamp")[0] == 1532402927612951
    assert sample_data.column("is_key_frame").tolist().count(False) == 2
    assert sample_data.column("filename")[0] == tiny_records["sample_data"][0]["filename"]
    intrinsic = db.table("calibrated_sensor").column("camera_intrinsic")
    assert intrinsic.shape == (4, 3, 3)
    assert intrinsic[0, 0, 0] == 1266.4 and np.isnan(intrinsic[1]).all()
    assert db.table("map").rows("log_tokens").tolist() == [[0]]


def test_columns_are_read_only(db):
    with pytest.raises(ValueError):
        db.table("ego_pose").column("translation")[0, 0] = 1.0
    with pytest.raises(ValueError):
        db.table("sample").rows("next")[0] = 0


def test_unknown_fields_and_non_reference_rows_are_key_errors(db):
    with pytest.raises(KeyError, match="table scene has no field 'nmae'"):
        db.table("scene").column("nmae")
    with pytest.raises(KeyError, match="scene.name is not a token reference"):
        db.table("scene").rows("name")
    with pytest.raises(KeyError, match="no table 'scenes'"):
        db.table("scenes")


def test_token_lookup(db, tiny_records):
    samples = db.table("sample")
    tokens = [r["token"] for r in tiny_records["sample"]]
    assert samples.index(tokens[3]) == 3
    assert samples.indices([tokens[4], tokens[0], tokens[4]]).tolist() == [4, 0, 4]
    assert samples.indices(np.array(tokens).reshape(5, 1)).shape == (5, 1)
    assert samples.indices([]).tolist() == []
    assert samples.indices(["nope", tokens[1]], allow_missing=True).tolist() == [-1, 1]
    with pytest.raises(DataFormatError) as caught:
        samples.indices([tokens[0], "nope"])
    assert str(caught.value) == f"{samples.path}: no sample record has token 'nope'"
    with pytest.raises(TypeError):
        samples.indices(tokens[0])


def test_get_adds_the_devkit_reverse_fields(db, tiny_records):
    samples = tiny_records["sample"]
    sample_data = tiny_records["sample_data"]
    annotations = tiny_records["sample_annotation"]
    sample = db.get("sample", samples[1]["token"])
    key_frames = {r["filename"].split("/")[1]: r["token"] for r in sample_data
                  if r["sample_token"] == samples[1]["token"] and r["is_key_frame"]}
    assert sample == {**samples[1], "data": key_frames,
                      "anns": [annotations[1]["token"], annotations[4]["token"]]}
    assert set(key_frames) == {"CAM_FRONT", "LIDAR_TOP"}
    assert db.get("sample_data", sample_data[0]["token"]) == {
        **sample_data[0], "channel": "CAM_FRONT", "sensor_modality": "camera"}
    assert db.get("sample_annotation", annotations[3]["token"]) == {
        **annotations[3], "category_name": "human.pedestrian.adult"}
    assert db.get("log", tiny_records["log"][0]["token"]) == tiny_records["log"][0]
    with pytest.raises(DataFormatError, match="no scene record has token 'nope'"):
        db.get("scene", "nope")


def test_sample_level_indexes(db, tiny_records):
    samples = [r["token"] for r in tiny_records["sample"]]
    assert [db.sample_annotation_rows(t).tolist() for t in samples] == [
        [0, 3], [1, 4], [2], [5], []]
    assert db.sample_annotation_rows(samples[0]).dtype == np.int64
    assert db.annotation_category_names().tolist() == [
        "vehicle.car"] * 3 + ["human.pedestrian.adult"] * 2 + ["vehicle.bicycle"]
    assert db.keyframe_data(samples[4]) == db.get("sample", samples[4])["data"]
    channels = db.sample_data_channels()
    assert channels.tolist().count("LIDAR_TOP") == 7 and channels[0] == "CAM_FRONT"
    assert set(db.sample_data_modalities().tolist()) == {"camera", "lidar"}


def test_sample_tokens_of_scene_walk_in_time_order(db, tiny_records):
    samples = [r["token"] for r in tiny_records["sample"]]
    scenes = [r["token"] for r in tiny_records["scene"]]
    assert db.sample_tokens_of_scene(scenes[0]) == samples[:3]
    assert db.sample_tokens_of_scene(scenes[1]) == samples[3:]


def test_poses_and_calibration(db, tiny_records):
    camera = tiny_records["sample_data"][1]
    lidar = next(r for r in tiny_records["sample_data"] if r["filename"].startswith("sweeps/"))
    rotation, translation = db.ego_pose_of(lidar["token"])
    pose = next(r for r in tiny_records["ego_pose"] if r["token"] == lidar["ego_pose_token"])
    assert rotation.tolist() == pose["rotation"] and translation.tolist() == pose["translation"]
    rotation, translation, intrinsic = db.calibration_of(camera["token"])
    assert rotation.tolist() == [0.5, -0.5, 0.5, -0.5] and translation.tolist() == [1.7, 0.0, 1.5]
    assert intrinsic.tolist() == [[1266.4, 0.0, 816.3], [0.0, 1266.4, 491.5], [0.0, 0.0, 1.0]]
    assert db.calibration_of(lidar["token"])[2] is None


def test_sensor_files_are_read_through_the_db(db, tiny_dataroot, tiny_records):
    lidar = next(r for r in tiny_records["sample_data"] if r["fileformat"] == "pcd")
    camera = tiny_records["sample_data"][0]
    assert db.data_path(lidar["token"]) == tiny_dataroot / lidar["filename"]
    points = np.arange(15, dtype=np.float32).reshape(3, 5)
    write_pcd_bin(db.data_path(lidar["token"]), points)
    np.testing.assert_array_equal(db.read_lidar(lidar["token"]), points)
    write_jpeg(db.data_path(camera["token"]), np.full((900, 1600, 3), 128, np.uint8))
    assert db.read_image(camera["token"]).shape == (900, 1600, 3)
    with pytest.raises(SianmsError, match=f"sample_data {camera['token']} is from CAM_FRONT "
                                          r"\(camera\), not a lidar"):
        db.read_lidar(camera["token"])
    with pytest.raises(SianmsError, match="not a camera"):
        db.read_image(lidar["token"])
    missing = tiny_records["sample_data"][2]
    with pytest.raises(DataFormatError, match=f"record {missing['token']}: image file not found"):
        db.read_image(missing["token"])


# --------------------------------------------------------------------------- malformed input


def test_an_image_of_another_size_than_its_record_is_named(db, tiny_records):
    """Boxes are clipped to the record's size and features pooled from the file: the two must agree."""
    camera = tiny_records["sample_data"][0]
    write_jpeg(db.data_path(camera["token"]), np.full((450, 800, 3), 128, np.uint8))
    with pytest.raises(DataFormatError) as error:
        db.read_image(camera["token"])
    assert str(error.value) == (f"{db.data_path(camera['token'])}: is 800x450 pixels, but its sample_data record "
                                f"{camera['token']} says width 1600, height 900")


def test_missing_version_folder(tmp_path):
    with pytest.raises(DataFormatError) as caught:
        NuScenesDB(tmp_path, "v1.0-trainval")
    assert str(caught.value) == (
        f"{tmp_path / 'v1.0-trainval'}: version folder not found (expected <dataroot>/<version>/)")


def test_missing_table_files(tiny_dataroot):
    (tiny_dataroot / VERSION / "sample.json").unlink()
    (tiny_dataroot / VERSION / "map.json").unlink()
    error = _load_error(tiny_dataroot)
    assert str(error) == (
        f"{tiny_dataroot / VERSION / 'sample.json'}: table file not found (also missing: map)")
    (tiny_dataroot / VERSION / "sample.json").mkdir()
    assert str(_load_error(tiny_dataroot)) == (
        f"{tiny_dataroot / VERSION / 'sample.json'}: is a folder, not a table file (also missing: map)")


def test_invalid_json_names_line_and_column(tiny_dataroot):
    path = tiny_dataroot / VERSION / "scene.json"
    path.write_text('[\n{"token": "s1",\n "name": }\n]')
    error = _load_error(tiny_dataroot)
    assert str(error).startswith(f"{path}: invalid JSON at line 3, column 10: ")


def test_invalid_utf8_is_reported(tiny_dataroot):
    path = tiny_dataroot / VERSION / "log.json"
    path.write_bytes(b'[{"token": "\xff"}]')
    assert str(_load_error(tiny_dataroot)) == f"{path}: not valid UTF-8 at byte 12"


def test_top_level_must_be_a_list(tiny_dataroot, rewrite_table):
    path = rewrite_table("log", lambda records: {"records": records})
    assert str(_load_error(tiny_dataroot)) == (
        f"{path}: top level must be a list of records, got dict")


def test_records_must_be_objects(tiny_dataroot, rewrite_table):
    path = rewrite_table("log", lambda records: records + [["token", "x"]])
    assert str(_load_error(tiny_dataroot)) == f"{path}: record at position 1 is a list, not an object"


def test_missing_field(tiny_dataroot, rewrite_table, tiny_records):
    path = rewrite_table("scene", lambda records: records[1].pop("nbr_samples") and None)
    error = _load_error(tiny_dataroot)
    token = tiny_records["scene"][1]["token"]
    assert str(error) == f"{path}: record {token}: field 'nbr_samples': missing"
    assert (error.token, error.field) == (token, "nbr_samples")


def test_missing_token_names_the_position(tiny_dataroot, rewrite_table):
    path = rewrite_table("attribute", lambda records: records[2].pop("token") and None)
    assert str(_load_error(tiny_dataroot)) == (
        f"{path}: field 'token': record at position 2: missing")


@pytest.mark.parametrize("table, row, field, value, problem", [
    ("scene", 0, "nbr_samples", "3", "expected an integer, got '3' (str)"),
    ("sample", 2, "timestamp", 1532402928647951.0, "expected an integer, got 1532402928647951.0 (float)"),
    ("sample_annotation", 4, "translation", [1.0, 2.0], "expected a list of 3 finite numbers, got [1.0, 2.0] (list)"),
    ("sample_annotation", 1, "size", "big", "expected a list of 3 finite numbers, got 'big' (str)"),
    ("sample_annotation", 2, "rotation", [1, 0, False, 0],
     "expected a list of 4 finite numbers, got [1, 0, False, 0] (list)"),
    ("sample_annotation", 0, "num_radar_pts", True, "expected an integer, got True (bool)"),
    ("sample_annotation", 3, "attribute_tokens", "abc", "expected a list of attribute tokens, got 'abc' (str)"),
    ("sample_annotation", 5, "visibility_token", None, "expected a visibility token or \"\", got None (NoneType)"),
    ("sample_data", 3, "is_key_frame", 1, "expected true or false, got 1 (int)"),
    ("sample_data", 0, "filename", 7, "expected a string without NUL, got 7 (int)"),
    # numpy's string arrays drop trailing NULs: read as it stands, "...\x00" would name another scene
    ("scene", 0, "name", "scene-0001\x00", "expected a string without NUL, got 'scene-0001\\x00' (str)"),
    ("sample", 1, "prev", "a\x00", "expected a sample token or \"\", got 'a\\x00' (str)"),
    ("sample_data", 5, "sample_token", "", "expected a sample token, got '' (str)"),
    ("ego_pose", 1, "timestamp", 2**63, "expected an integer, got 9223372036854775808 (int)"),
    ("calibrated_sensor", 0, "camera_intrinsic", [[1, 0], [0, 1]],
     "expected [] or a 3x3 pinhole matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]] of finite numbers, fx and fy > 0, "
     "got [[1, 0], [0, 1]] (list)"),
    ("map", 0, "log_tokens", [""], "expected a list of log tokens, got [''] (list)"),
])
def test_wrong_field_types(tiny_dataroot, rewrite_table, tiny_records, table, row, field, value,
                           problem):
    path = rewrite_table(table, lambda records: records[row].__setitem__(field, value))
    token = tiny_records[table][row]["token"]
    assert str(_load_error(tiny_dataroot)) == f"{path}: record {token}: field '{field}': {problem}"


@pytest.mark.parametrize("chunk_bytes", [32 * 2**20, 300])
def test_nan_is_read_then_named_by_record_and_field(tiny_dataroot, rewrite_table, tiny_records,
                                                    monkeypatch, chunk_bytes):
    # orjson rejects NaN and the json module reads it (sianms_cli.io.decode_json), so NaN is
    # a wrong value of a field, whole or in pieces, not a syntax error.
    monkeypatch.setattr(loader, "_CHUNK_BYTES", chunk_bytes)
    path = rewrite_table("sample_annotation",
                         lambda records: records[4].__setitem__("translation", [math.nan, 2.0, 0.5]))
    token = tiny_records["sample_annotation"][4]["token"]
    assert str(_load_error(tiny_dataroot)) == (
        f"{path}: record {token}: field 'translation': "
        "expected a list of 3 finite numbers, got [nan, 2.0, 0.5] (list)")


_SIZE_PROBLEM = "expected 3 sizes greater than 0 and at most 1,000 m, got "
_ROTATION_PROBLEM = ("expected a quaternion that can be normalised "
                     "(largest |component| in [1e-150, 1e+150]), got ")


@pytest.mark.parametrize("table, row, field, value, problem", [
    ("sample_annotation", 1, "size", [-1, 2, 3], _SIZE_PROBLEM + "[-1, 2, 3]"),
    ("sample_annotation", 2, "size", [1.5, 0.0, 3], _SIZE_PROBLEM + "[1.5, 0.0, 3]"),
    ("sample_annotation", 2, "size", [1e308, 2.0, 1.5], _SIZE_PROBLEM + "[1e+308, 2.0, 1.5]"),
    ("sample_annotation", 0, "num_lidar_pts", -500, "expected a count of 0 or more, got -500"),
    ("sample_annotation", 5, "num_radar_pts", -1, "expected a count of 0 or more, got -1"),
    ("sample_annotation", 3, "rotation", [0, 0, 0, 0], _ROTATION_PROBLEM + "[0, 0, 0, 0]"),
    ("sample_annotation", 4, "rotation", [1e300, 1e300, 0, 0], _ROTATION_PROBLEM + "[1e+300, 1e+300, 0, 0]"),
    ("ego_pose", 2, "rotation", [0.0, 0.0, 0.0, 0.0], _ROTATION_PROBLEM + "[0.0, 0.0, 0.0, 0.0]"),
    ("ego_pose", 1, "rotation", [1e-200, 0, 0, 0], _ROTATION_PROBLEM + "[1e-200, 0, 0, 0]"),
    ("calibrated_sensor", 1, "rotation", [0, 0, 0, 0], _ROTATION_PROBLEM + "[0, 0, 0, 0]"),
    ("instance", 0, "nbr_annotations", -3, "expected a count of 0 or more, got -3"),
    ("sample_data", 1, "width", -5, "expected a width of 0 or more pixels (0: not an image), got -5"),
    ("sample_data", 2, "height", -1, "expected a height of 0 or more pixels (0: not an image), got -1"),
    # numpy had warned of overflow on stderr while projecting these, and gone on
    ("sample_annotation", 0, "translation", [1e308, 1e308, 0], "expected 3 coordinates within ±1e+08 m, got "
                                                               "[1e+308, 1e+308, 0]"),
    ("ego_pose", 0, "translation", [0, -2e8, 0], "expected 3 coordinates within ±1e+08 m, got [0, -200000000.0, 0]"),
    ("calibrated_sensor", 1, "translation", [1e9, 0, 1.5], "expected 3 coordinates within ±1e+08 m, got "
                                                           "[1000000000.0, 0, 1.5]"),
    ("calibrated_sensor", 0, "camera_intrinsic", [[1266.4, 0, 1e308], [0, 1266.4, 491.5], [0, 0, 1]],
     "expected entries within ±1e+06 px, got [[1266.4, 0, 1e+308], [0, 1266.4, 491.5], [0, 0, 1]]"),
])
def test_values_no_record_can_hold(tiny_dataroot, rewrite_table, tiny_records, table, row, field,
                                   value, problem):
    path = rewrite_table(table, lambda records: records[row].__setitem__(field, value))
    token = tiny_records[table][row]["token"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow on the way to the error
        error = _load_error(tiny_dataroot)
    assert str(error) == f"{path}: record {token}: field '{field}': {problem}"


def test_values_within_the_rules_load(tiny_dataroot, rewrite_table):
    # An unnormalised rotation is a rotation (the devkit normalises too); no points is a count.
    def edge_values(records):
        records[0].update(rotation=[2.0, 0, 0, 1e-300], num_lidar_pts=0, num_radar_pts=0)
        records[1].update(rotation=[0, 0, 0, -1e150], size=[1e-9, 1e-9, 1e-9])

    rewrite_table("sample_annotation", edge_values)
    annotations = NuScenesDB(tiny_dataroot, VERSION).table("sample_annotation")
    assert annotations.column("rotation")[:2].tolist() == [[2.0, 0, 0, 1e-300], [0, 0, 0, -1e150]]


def test_a_camera_key_frame_without_an_image_size_is_named(tiny_dataroot, rewrite_table, tiny_records):
    """Width 0 is a LiDAR or radar record's; on a camera's key frame the rig has no image."""
    camera = next(i for i, record in enumerate(tiny_records["sample_data"])
                  if record["is_key_frame"] and "/CAM_" in record["filename"])
    path = rewrite_table("sample_data", lambda records: records[camera].__setitem__("width", 0))
    db = NuScenesDB(tiny_dataroot, VERSION)
    with pytest.raises(DataFormatError) as error:
        sample_rigs(db, db.table("sample").tokens)
    assert str(error.value) == (f"{path}: record {tiny_records['sample_data'][camera]['token']}: field 'width': "
                                "a camera key frame needs a positive image width, got 0")


def test_a_camera_calibration_without_an_intrinsic_is_named(tiny_dataroot, rewrite_table, tiny_records):
    """[] is a LiDAR's or radar's intrinsic; a camera's frustums would be silently dropped without one."""
    camera = next(record for record in tiny_records["sample_data"]
                  if record["is_key_frame"] and "/CAM_" in record["filename"])
    calibration = camera["calibrated_sensor_token"]
    path = rewrite_table("calibrated_sensor", lambda records: next(
        record for record in records if record["token"] == calibration).__setitem__("camera_intrinsic", []))
    db = NuScenesDB(tiny_dataroot, VERSION)
    with pytest.raises(DataFormatError) as error:
        sample_rigs(db, db.table("sample").tokens)
    assert str(error.value).startswith(f"{path}: record ")
    assert str(error.value).endswith("field 'camera_intrinsic': a camera's calibration needs its intrinsic matrix, "
                                     "got []")


def test_empty_token_names_the_position(tiny_dataroot, rewrite_table):
    path = rewrite_table("log", lambda records: records[0].__setitem__("token", ""))
    assert str(_load_error(tiny_dataroot)) == (
        f"{path}: field 'token': record at position 0: expected a non-empty string without NUL, got '' (str)")


def test_duplicate_token(tiny_dataroot, rewrite_table, tiny_records):
    def duplicate(records):
        records[4]["token"] = records[1]["token"]

    path = rewrite_table("sample_data", duplicate)
    token = tiny_records["sample_data"][1]["token"]
    assert str(_load_error(tiny_dataroot)) == (
        f"{path}: record {token}: field 'token': duplicate token (records at positions 1 and 4)")


@pytest.mark.parametrize("table, row, field, value, referenced", [
    ("sample_annotation", 2, "instance_token", "ghost", "instance"),
    ("sample_annotation", 3, "prev", "ghost", "sample_annotation"),
    ("sample_annotation", 1, "attribute_tokens", ["ghost"], "attribute"),
    ("sample_data", 6, "calibrated_sensor_token", "ghost", "calibrated_sensor"),
    ("scene", 1, "first_sample_token", "ghost", "sample"),
    ("instance", 0, "category_token", "ghost", "category"),
    ("map", 0, "log_tokens", ["ghost"], "log"),
])
def test_dangling_references(tiny_dataroot, rewrite_table, tiny_records, table, row, field, value,
                             referenced):
    path = rewrite_table(table, lambda records: records[row].__setitem__(field, value))
    token = tiny_records[table][row]["token"]
    assert str(_load_error(tiny_dataroot)) == (
        f"{path}: record {token}: field '{field}': refers to {referenced} token 'ghost', "
        f"which is not in {referenced}.json")


def test_a_token_list_longer_than_its_table_is_refused_before_it_is_padded(tiny_dataroot, rewrite_table, tiny_records):
    """200,000 copies of one attribute token on one annotation had padded every annotation's list to
    that width (30 GB on the mini)."""
    attributes = tiny_records["attribute"]
    path = rewrite_table("sample_annotation", lambda records: records[1].__setitem__(
        "attribute_tokens", [attributes[0]["token"]] * (len(attributes) + 1)))
    token = tiny_records["sample_annotation"][1]["token"]
    assert str(_load_error(tiny_dataroot)) == (
        f"{path}: record {token}: field 'attribute_tokens': lists {len(attributes) + 1} tokens, more than "
        f"attribute.json's {len(attributes)}: one repeats")


@pytest.mark.parametrize("filename, problem", [
    ("../outside.jpg", "resolves outside the dataroot"),
    ("/data/sets/nuscenes/samples/x.jpg", "is absolute; it must be relative to the dataroot"),
])
def test_filename_escaping_the_dataroot(tiny_dataroot, rewrite_table, tiny_records, filename,
                                        problem):
    path = rewrite_table("sample_data", lambda records: records[7].__setitem__("filename", filename))
    token = tiny_records["sample_data"][7]["token"]
    assert str(_load_error(tiny_dataroot)).startswith(
        f"{path}: record {token}: field 'filename': '{filename}' {problem}")


def test_dots_inside_names_are_fine(tiny_dataroot, rewrite_table):
    rewrite_table("sample_data", lambda records: records[7].__setitem__("filename", "samples/a..b/x.jpg"))
    db = NuScenesDB(tiny_dataroot, VERSION)
    assert db.table("sample_data").column("filename")[7] == "samples/a..b/x.jpg"


def test_extra_fields_and_extra_tables_are_ignored(tiny_dataroot, rewrite_table, tiny_records):
    def add_index(records):
        for i, record in enumerate(records):
            record["index"] = i

    rewrite_table("category", add_index)
    (tiny_dataroot / VERSION / "lidarseg.json").write_text("not even json")
    db = NuScenesDB(tiny_dataroot, VERSION)
    assert db.table("category").record(0) == tiny_records["category"][0]


# --------------------------------------------------------------------------- scene chains


def _scene_error(dataroot, scene_row=0):
    db = NuScenesDB(dataroot, VERSION)
    with pytest.raises(DataFormatError) as caught:
        db.sample_tokens_of_scene(db.table("scene").tokens[scene_row])
    return caught.value


def test_chain_that_stops_early(tiny_dataroot, rewrite_table, tiny_records):
    path = rewrite_table("sample", lambda records: records[1].__setitem__("next", ""))
    samples = tiny_records["sample"]
    assert str(_scene_error(tiny_dataroot)) == (
        f"{path}: record {samples[1]['token']}: field 'next': chain of scene "
        f"{tiny_records['scene'][0]['token']} ends before its last sample {samples[2]['token']}")


def test_chain_that_leaves_the_scene(tiny_dataroot, rewrite_table, tiny_records):
    samples = tiny_records["sample"]
    path = rewrite_table("sample", lambda records: records[0].__setitem__("next", samples[3]["token"]))
    scenes = tiny_records["scene"]
    assert str(_scene_error(tiny_dataroot)) == (
        f"{path}: record {samples[0]['token']}: field 'next': next sample {samples[3]['token']} "
        f"belongs to scene {scenes[1]['token']}, not {scenes[0]['token']}")


def test_chain_that_loops(tiny_dataroot, rewrite_table, tiny_records):
    samples = tiny_records["sample"]
    path = rewrite_table("sample", lambda records: records[1].__setitem__("next", samples[0]["token"]))
    assert str(_scene_error(tiny_dataroot)) == (
        f"{path}: record {samples[1]['token']}: field 'next': next sample {samples[0]['token']} "
        "was already visited (a loop)")


def test_chain_that_goes_on_after_its_last_sample(tiny_dataroot, rewrite_table, tiny_records):
    samples = tiny_records["sample"]
    path = rewrite_table("sample", lambda records: records[2].__setitem__("next", samples[0]["token"]))
    assert str(_scene_error(tiny_dataroot)) == (
        f"{path}: record {samples[2]['token']}: field 'next': the last sample of scene "
        f"{tiny_records['scene'][0]['token']} has a next sample, {samples[0]['token']}")


def test_the_metrics_split_blames_a_broken_chain_on_sample_json(tiny_dataroot, rewrite_table, tiny_records):
    from sianms_cli.metrics.dataset import eval_split
    from sianms_cli.nuscenes.splits import split_scene_names

    samples, scene = tiny_records["sample"], tiny_records["scene"][0]
    split = next(name for name in ("mini_train", "mini_val") if scene["name"] in split_scene_names(name, VERSION))
    path = rewrite_table("sample", lambda records: records[1].__setitem__("scene_token",
                                                                          tiny_records["scene"][1]["token"]))
    with pytest.raises(DataFormatError, match=f"{path}: record {samples[0]['token']}: field 'next'"):
        eval_split(NuScenesDB(tiny_dataroot, VERSION), split)


def test_first_sample_of_another_scene(tiny_dataroot, rewrite_table, tiny_records):
    samples = tiny_records["sample"]
    scenes = tiny_records["scene"]
    path = rewrite_table(
        "scene", lambda records: records[1].__setitem__("first_sample_token", samples[0]["token"]))
    assert str(_scene_error(tiny_dataroot, scene_row=1)) == (
        f"{path}: record {scenes[1]['token']}: field 'first_sample_token': first sample "
        f"{samples[0]['token']} belongs to scene {scenes[0]['token']}")


def test_sample_count_differs_from_nbr_samples(tiny_dataroot, rewrite_table, tiny_records):
    path = rewrite_table("scene", lambda records: records[0].__setitem__("nbr_samples", 4))
    assert str(_scene_error(tiny_dataroot)) == (
        f"{path}: record {tiny_records['scene'][0]['token']}: field 'nbr_samples': "
        "4 samples declared, 3 along the first/next chain")


def test_loaded_tables_hold_no_python_object_per_record(db):
    for name in TABLE_NAMES:
        table = db.table(name)
        for field in table.fields:
            column = table.rows(field) if table.schema[field].table else table.column(field)
            assert column.dtype != object, (name, field)
    assert re.fullmatch(r"Table\('sample', 5 records\)", repr(db.table("sample")))


# --------------------------------------------------------------------------- decoding in pieces


@pytest.fixture
def small_pieces(monkeypatch):
    """Decode every table file larger than 300 bytes in pieces of about 300 bytes."""
    monkeypatch.setattr(loader, "_CHUNK_BYTES", 300)


def test_round_trip_when_decoding_in_pieces(small_pieces, tiny_dataroot, tiny_records):
    assert (tiny_dataroot / VERSION / "sample_data.json").stat().st_size > 3000
    db = NuScenesDB(tiny_dataroot, VERSION)
    for name in TABLE_NAMES:
        table = db.table(name)
        assert [table.record(i) for i in range(len(table))] == tiny_records[name], name
    # Pieces without attributes and pieces with one still give one (N, 1) array.
    assert db.table("sample_annotation").rows("attribute_tokens").shape == (6, 1)


def test_syntax_error_in_a_later_piece_names_the_files_line(small_pieces, tiny_dataroot):
    path = tiny_dataroot / VERSION / "sample_data.json"
    lines = path.read_text().splitlines()
    lines[9] = lines[9].replace('"is_key_frame": true', '"is_key_frame": tru')
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFormatError) as whole:
        read_json(path)
    assert str(whole.value).startswith(f"{path}: invalid JSON at line 10, column ")
    assert str(_load_error(tiny_dataroot)) == str(whole.value)


def test_errors_in_later_pieces_name_positions_in_the_file(small_pieces, tiny_dataroot,
                                                           rewrite_table, tiny_records):
    path = rewrite_table("sample_data", lambda records: records[10].pop("token") and None)
    assert str(_load_error(tiny_dataroot)) == (
        f"{path}: field 'token': record at position 10: missing")
    path = rewrite_table("sample_data", lambda records: records.__setitem__(10, ["x"]))
    assert str(_load_error(tiny_dataroot)) == (
        f"{path}: record at position 10 is a list, not an object")


def test_duplicates_and_dangling_references_across_pieces(small_pieces, tiny_dataroot,
                                                          rewrite_table, tiny_records):
    tokens = [r["token"] for r in tiny_records["sample_data"]]

    def duplicate(records):
        records[11]["token"] = records[0]["token"]

    path = rewrite_table("sample_data", duplicate)
    assert str(_load_error(tiny_dataroot)) == (
        f"{path}: record {tokens[0]}: field 'token': duplicate token "
        "(records at positions 0 and 11)")
    rewrite_table("sample_data", lambda records: records[11].__setitem__("token", tokens[11]))
    rewrite_table("sample_data", lambda records: records[11].__setitem__("sample_token", "ghost"))
    assert str(_load_error(tiny_dataroot)) == (
        f"{path}: record {tokens[11]}: field 'sample_token': refers to sample token 'ghost', "
        "which is not in sample.json")


def test_value_rules_name_positions_in_later_pieces(small_pieces, tiny_dataroot, rewrite_table,
                                                    tiny_records):
    path = rewrite_table("ego_pose", lambda records: records[11].__setitem__("rotation", [0, 0, 0, 0]))
    token = tiny_records["ego_pose"][11]["token"]
    assert str(_load_error(tiny_dataroot)) == (
        f"{path}: record {token}: field 'rotation': {_ROTATION_PROBLEM}[0, 0, 0, 0]")


def test_a_large_file_that_is_not_a_list(small_pieces, tiny_dataroot, rewrite_table):
    path = rewrite_table("sample_data", lambda records: {"records": records})
    assert str(_load_error(tiny_dataroot)) == (
        f"{path}: top level must be a list of records, got dict")
