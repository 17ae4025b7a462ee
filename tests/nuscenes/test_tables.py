import hashlib

import pytest

from sianms_cli.nuscenes.tables import (
    ATTRIBUTES,
    CAMERA_CHANNELS,
    CATEGORIES,
    INT,
    INTRINSIC,
    SCHEMAS,
    SENSORS,
    STR,
    TABLE_NAMES,
    TOKEN,
    VISIBILITIES,
    Field,
    check_value,
    optional_ref,
    ref,
    ref_list,
    vector,
)


def test_table_names_are_the_devkit_order():
    assert TABLE_NAMES == (
        "category", "attribute", "visibility", "instance", "sensor", "calibrated_sensor",
        "ego_pose", "log", "scene", "sample", "sample_data", "sample_annotation", "map",
    )
    assert set(SCHEMAS) == set(TABLE_NAMES)


def test_every_table_has_a_token_and_references_name_real_tables():
    for name, schema in SCHEMAS.items():
        assert schema["token"] == TOKEN, name
        for field, kind in schema.items():
            if kind.table is not None:
                assert kind.table in TABLE_NAMES, (name, field)


def test_schema_fields_match_the_nuscenes_schema():
    assert list(SCHEMAS["sample_annotation"]) == [
        "token", "sample_token", "instance_token", "visibility_token", "attribute_tokens",
        "translation", "size", "rotation", "prev", "next", "num_lidar_pts", "num_radar_pts",
    ]
    assert set(SCHEMAS["sample_data"]) == {
        "token", "sample_token", "ego_pose_token", "calibrated_sensor_token", "timestamp",
        "fileformat", "is_key_frame", "height", "width", "filename", "prev", "next",
    }
    assert SCHEMAS["sample_annotation"]["size"] == vector(3)
    assert SCHEMAS["ego_pose"]["rotation"] == vector(4)
    assert SCHEMAS["sample_annotation"]["visibility_token"] == optional_ref("visibility")
    assert SCHEMAS["sample_annotation"]["attribute_tokens"] == ref_list("attribute")
    assert SCHEMAS["map"]["log_tokens"] == ref_list("log")
    assert SCHEMAS["sample_data"]["next"] == optional_ref("sample_data")
    assert SCHEMAS["instance"]["category_token"] == ref("category")
    assert SCHEMAS["calibrated_sensor"]["camera_intrinsic"] == INTRINSIC
    assert "index" not in SCHEMAS["category"]


def test_vocabularies_have_the_real_sizes_and_names():
    assert len(CATEGORIES) == 23 and len({c.name for c in CATEGORIES}) == 23
    assert {"animal", "vehicle.car", "movable_object.trafficcone",
            "static_object.bicycle_rack"} <= {c.name for c in CATEGORIES}
    assert [a.name for a in ATTRIBUTES] == [
        "vehicle.moving", "vehicle.stopped", "vehicle.parked", "cycle.with_rider",
        "cycle.without_rider", "pedestrian.moving", "pedestrian.standing",
        "pedestrian.sitting_lying_down",
    ]
    assert [(v.token, v.level) for v in VISIBILITIES] == [
        ("1", "v0-40"), ("2", "v40-60"), ("3", "v60-80"), ("4", "v80-100"),
    ]
    assert VISIBILITIES[1].description == "visibility of whole object is between 40 and 60%"


def test_sensors_carry_real_tokens_and_md5_radar_tokens():
    by_channel = {s.channel: s for s in SENSORS}
    assert len(SENSORS) == 12
    assert by_channel["CAM_FRONT"].token == "725903f5b62f56118f4094b46a4470d8"
    assert by_channel["LIDAR_TOP"].token == "dc8b396651c05aedbb9cdaae573bb567"
    assert by_channel["CAM_BACK_LEFT"].token == "a89643a5de885c6486df2232dc954da2"
    for sensor in SENSORS:
        if sensor.modality == "radar":
            assert sensor.token == hashlib.md5(sensor.channel.encode()).hexdigest()
    assert [s.modality for s in SENSORS].count("camera") == 6
    assert CAMERA_CHANNELS == ("CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_BACK_RIGHT", "CAM_BACK",
                               "CAM_BACK_LEFT", "CAM_FRONT_LEFT")


@pytest.mark.parametrize("field, value", [
    (TOKEN, "abc"), (INT, 0), (INT, 2**63 - 1), (Field("bool"), False), (vector(3), [1, 2.5, -3]),
    (INTRINSIC, []), (INTRINSIC, [[1, 0, 2], [0, 1, 3], [0, 0, 1]]), (optional_ref("sample"), ""),
    (ref("sample"), "t"), (ref_list("log"), []), (ref_list("log"), ["a", "b"]), (Field("str"), ""),
])
def test_check_value_accepts(field, value):
    assert check_value(field, value) is None


@pytest.mark.parametrize("field, value, problem", [
    (INT, "40", "expected an integer, got '40' (str)"),
    (INT, True, "expected an integer, got True (bool)"),
    (INT, 2**63, "expected an integer, got 9223372036854775808 (int)"),
    (INT, 3.0, "expected an integer, got 3.0 (float)"),
    (TOKEN, "", "expected a non-empty string without NUL, got '' (str)"),
    (TOKEN, "a\x00", "expected a non-empty string without NUL, got 'a\\x00' (str)"),
    (STR, "scene-0001\x00", "expected a string without NUL, got 'scene-0001\\x00' (str)"),
    (vector(3), [1.0, 2.0], "expected a list of 3 finite numbers, got [1.0, 2.0] (list)"),
    (vector(3), [1.0, True, 2.0], "expected a list of 3 finite numbers, got [1.0, True, 2.0] (list)"),
    (vector(3), [1.0, float("nan"), 2.0], "expected a list of 3 finite numbers, got [1.0, nan, 2.0] (list)"),
    (vector(3), (1.0, 2.0, 3.0), "expected a list of 3 finite numbers, got (1.0, 2.0, 3.0) (tuple)"),
    (INTRINSIC, [[0, 0, 0], [0, 0, 0], [0, 0, 1]], "expected [] or a 3x3 pinhole matrix [[fx, s, cx], [0, fy, cy], "
                                                   "[0, 0, 1]] of finite numbers, fx and fy > 0, got [[0, 0, 0], "
                                                   "[0, 0, 0], [0, 0, 1]] (list)"),
    (INTRINSIC, [[1, 0], [0, 1]], "expected [] or a 3x3 pinhole matrix [[fx, s, cx], [0, fy, cy], "
                                  "[0, 0, 1]] of finite numbers, fx and fy > 0, got [[1, 0], [0, 1]] (list)"),
    (ref("sample"), "", "expected a sample token, got '' (str)"),
    (optional_ref("sample"), None, "expected a sample token or \"\", got None (NoneType)"),
    (ref_list("attribute"), "abc", "expected a list of attribute tokens, got 'abc' (str)"),
    (ref_list("attribute"), [""], "expected a list of attribute tokens, got [''] (list)"),
    (ref_list("attribute"), ["a\x00"], "expected a list of attribute tokens, got ['a\\x00'] (list)"),
])
def test_check_value_names_the_problem(field, value, problem):
    assert check_value(field, value) == problem


@pytest.mark.parametrize("matrix", [
    [[800, 0, 400], [0, 800, 300], [0, 0, 2]], [[800, 0, 400], [1, 800, 300], [0, 0, 1]],
    [[800, 0, 400], [0, -800, 300], [0, 0, 1]], [[800, 0, 400], [0, 800, 300], [0, 1, 1]],
])
def test_an_intrinsic_rays_cannot_be_cast_from_is_refused(matrix):
    assert check_value(INTRINSIC, matrix).startswith("expected [] or a 3x3 pinhole matrix")


def test_check_value_shortens_long_values():
    problem = check_value(INT, "x" * 100)
    assert problem == "expected an integer, got '" + "x" * 56 + "... (str)"
