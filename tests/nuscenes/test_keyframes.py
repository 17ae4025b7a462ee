"""Sample records as arrays agree with the loader's record-by-record look-ups."""

import copy

import numpy as np
import pytest

from sianms_cli.nuscenes.keyframes import keyframe_rows, sensor_records, sweep_rows
from sianms_cli.errors import DataFormatError
from sianms_cli.nuscenes.loader import NuScenesDB

VERSION = "v1.0-mini"
CHANNELS = ("CAM_FRONT", "LIDAR_TOP", "CAM_BACK")


@pytest.fixture
def db(tiny_dataroot):
    return NuScenesDB(tiny_dataroot, VERSION)


def test_keyframe_rows_are_the_devkits_sample_data(db):
    samples = db.table("sample")
    rows = keyframe_rows(db, np.arange(len(samples))[::-1], CHANNELS)
    tokens = db.table("sample_data").tokens
    for position, sample in enumerate(samples.tokens[::-1].tolist()):
        data = db.keyframe_data(sample)
        got = {channel: str(tokens[row]) for channel, row in zip(CHANNELS, rows[position]) if row >= 0}
        assert got == data and rows[position, 2] == -1  # no CAM_BACK in the tiny rig


def test_a_later_key_frame_of_a_channel_wins(tmp_path, tiny_records, write_dataset):
    records = copy.deepcopy(tiny_records)
    first = next(r for r in records["sample_data"] if r["is_key_frame"] and "CAM_FRONT" in r["filename"])
    later = {**first, "token": "f" * 32, "ego_pose_token": "e" * 32, "prev": "", "next": "",
             "timestamp": first["timestamp"] + 10, "filename": first["filename"].replace(".jpg", "b.jpg")}
    records["ego_pose"].append({**records["ego_pose"][0], "token": "e" * 32})
    records["sample_data"].append(later)
    write_dataset(tmp_path / "d", records)
    db = NuScenesDB(tmp_path / "d", VERSION)
    row = db.table("sample").index(first["sample_token"])
    found = keyframe_rows(db, np.array([row]), CHANNELS)[0, 0]
    assert db.table("sample_data").tokens[found] == "f" * 32 == db.keyframe_data(first["sample_token"])["CAM_FRONT"]


def test_sensor_records_are_the_loaders_poses_and_calibrations(db):
    sample_data = db.table("sample_data")
    rows = np.array([[0, len(sample_data) - 1], [3, -1]])
    records = sensor_records(db, rows)
    assert records.tokens.shape == (2, 2) and records.intrinsic.shape == (2, 2, 3, 3)
    for index in ((0, 0), (0, 1), (1, 0)):
        token = str(sample_data.tokens[rows[index]])
        assert records.tokens[index] == token and records.rows[index] == rows[index]
        rotation, translation = db.ego_pose_of(token)
        assert np.array_equal(records.ego_rotation[index], rotation)
        assert np.array_equal(records.ego_translation[index], translation)
        sensor_rotation, sensor_translation, intrinsic = db.calibration_of(token)
        assert np.array_equal(records.sensor_rotation[index], sensor_rotation)
        assert np.array_equal(records.sensor_translation[index], sensor_translation)
        assert np.isnan(records.intrinsic[index]).all() if intrinsic is None else np.array_equal(
            records.intrinsic[index], intrinsic)
        record = db.get("sample_data", token)
        assert records.timestamps[index] == record["timestamp"]
        assert records.previous[index] == (sample_data.index(record["prev"]) if record["prev"] else -1)
    assert (records.tokens[1, 1], records.timestamps[1, 1], records.previous[1, 1]) == ("", -1, -1)
    assert np.isnan(records.ego_rotation[1, 1]).all() and np.isnan(records.intrinsic[1, 1]).all()


def test_sweep_rows_follow_the_prev_chain(db):
    samples = db.table("sample").tokens.tolist()
    lidar = keyframe_rows(db, np.arange(len(samples)), ["LIDAR_TOP"])[:, 0]
    chain = sweep_rows(db, np.append(lidar, -1), 3)
    assert chain.shape == (len(samples) + 1, 4) and (chain[-1] == -1).all()
    sample_data = db.table("sample_data")
    for position in range(len(samples)):
        expected, token = [], str(sample_data.tokens[lidar[position]])
        while token and len(expected) < 4:
            expected.append(sample_data.index(token))
            token = db.get("sample_data", token)["prev"]
        assert chain[position].tolist() == expected + [-1] * (4 - len(expected))
    # The second sample of the first scene: its key frame, the sweep between, the first key frame.
    assert (chain[1] >= 0).sum() == 3 and not sample_data.column("is_key_frame")[chain[1, 1]]
    assert sweep_rows(db, lidar, 0).tolist() == lidar[:, None].tolist()


@pytest.mark.parametrize("link, problem", [
    ("itself", "not earlier"),  # had stacked one sweep several times, each with a lag of 0
    ("next", "not earlier"),  # had stacked a later sweep, its lag negative
    ("camera", "a CAM_FRONT record, not LIDAR_TOP's"),  # had said only "is from CAM_FRONT (camera), not a lidar"
])
def test_a_prev_link_that_loops_steps_forwards_or_leaves_the_sensor_is_named(tmp_path, tiny_records, write_dataset,
                                                                           link, problem):
    records = copy.deepcopy(tiny_records)
    lidar = [r for r in records["sample_data"] if r["is_key_frame"] and "LIDAR_TOP" in r["filename"]]
    edited = lidar[1]
    target = {"itself": edited["token"], "next": lidar[2]["token"],
              "camera": next(r["token"] for r in records["sample_data"] if "CAM_FRONT" in r["filename"])}[link]
    edited["prev"] = target
    write_dataset(tmp_path / "d", records)
    db = NuScenesDB(tmp_path / "d", VERSION)
    rows = keyframe_rows(db, np.arange(len(db.table("sample"))), ["LIDAR_TOP"])[:, 0]
    with pytest.raises(DataFormatError) as raised:
        sweep_rows(db, rows, 3)
    assert str(raised.value).startswith(f"{db.table('sample_data').path}: record {edited['token']}: field 'prev': "
                                        f"prev {target} is {problem}")
