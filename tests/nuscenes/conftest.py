"""A tiny, consistent nuScenes-format dataset for the nuscenes/ tests.

Two scenes named as the devkit's mini_val (scene-0103: 3 samples, scene-0916: 2 samples), one
log and map, CAM_FRONT and LIDAR_TOP calibrated per scene, a key frame of each per sample plus
one LIDAR_TOP sweep, and three instances (a car over 3 samples, a pedestrian over 2, a bicycle
over 1) with prev/next chains. Every token comes from make_token, so the build is
deterministic.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

import pytest

from sianms_cli.nuscenes.tables import ATTRIBUTES, CATEGORIES, SENSORS, TABLE_NAMES, VISIBILITIES
from sianms_cli.nuscenes.writer import DatasetWriter, attribute_token, category_token, make_token

VERSION = "v1.0-mini"
LOGFILE = "n015-2018-07-24-11-22-45+0800"
T0 = 1532402927647951
SCENES = {"scene-0103": 3, "scene-0916": 2}
SENSOR_TOKEN = {sensor.channel: sensor.token for sensor in SENSORS}
INTRINSIC = [[1266.4, 0.0, 816.3], [0.0, 1266.4, 491.5], [0.0, 0.0, 1.0]]

Records = dict[str, list[dict[str, Any]]]


def _static_records(tables: Records) -> None:
    for category in CATEGORIES:
        tables["category"].append({"token": category_token(category.name), "name": category.name,
                                   "description": category.description})
    for attribute in ATTRIBUTES:
        tables["attribute"].append({"token": attribute_token(attribute.name),
                                    "name": attribute.name, "description": attribute.description})
    for visibility in VISIBILITIES:
        tables["visibility"].append({"description": visibility.description,
                                     "token": visibility.token, "level": visibility.level})
    for sensor in SENSORS:
        tables["sensor"].append({"token": sensor.token, "channel": sensor.channel,
                                 "modality": sensor.modality})


def _link(records: list[dict[str, Any]]) -> None:
    """Fill prev/next along ``records`` in order."""
    for before, after in zip(records, records[1:]):
        before["next"] = after["token"]
        after["prev"] = before["token"]


def _sample_data(tables: Records, scene: str, channel: str, sample_token: str, timestamp: int,
                 key_frame: bool) -> dict[str, Any]:
    token = make_token("sample_data", scene, channel, timestamp)
    camera = channel.startswith("CAM")
    folder = "samples" if key_frame else "sweeps"
    extension = "jpg" if camera else "pcd.bin"
    tables["ego_pose"].append({"token": token, "timestamp": timestamp,
                               "rotation": [1.0, 0.0, 0.0, 0.0],
                               "translation": [10.0 + timestamp % 1000 / 100, -5.0, 0.0]})
    record = {
        "token": token, "sample_token": sample_token, "ego_pose_token": token,
        "calibrated_sensor_token": make_token("calibrated_sensor", scene, channel),
        "timestamp": timestamp, "fileformat": "jpg" if camera else "pcd",
        "is_key_frame": key_frame, "height": 900 if camera else 0, "width": 1600 if camera else 0,
        "filename": f"{folder}/{channel}/{LOGFILE}__{channel}__{timestamp}.{extension}",
        "prev": "", "next": "",
    }
    tables["sample_data"].append(record)
    return record


def build_tiny_records() -> Records:
    """All 13 tables of the tiny dataset as JSON-ready records, in writing order."""
    tables: Records = {name: [] for name in TABLE_NAMES}
    _static_records(tables)
    log_token = make_token("log", LOGFILE)
    tables["log"].append({"token": log_token, "logfile": LOGFILE, "vehicle": "n015",
                          "date_captured": "2018-07-24", "location": "singapore-onenorth"})
    map_token = make_token("map", "singapore-onenorth")
    tables["map"].append({"category": "semantic_prior", "token": map_token,
                          "filename": f"maps/{map_token}.png", "log_tokens": [log_token]})
    for scene_index, (scene, count) in enumerate(SCENES.items()):
        scene_token = make_token("scene", scene)
        for channel, translation in (("CAM_FRONT", [1.7, 0.0, 1.5]), ("LIDAR_TOP", [0.9, 0.0, 1.8])):
            tables["calibrated_sensor"].append({
                "token": make_token("calibrated_sensor", scene, channel),
                "sensor_token": SENSOR_TOKEN[channel], "translation": translation,
                "rotation": [0.5, -0.5, 0.5, -0.5] if channel == "CAM_FRONT" else [1.0, 0, 0, 0],
                "camera_intrinsic": INTRINSIC if channel == "CAM_FRONT" else [],
            })
        start = T0 + scene_index * 100_000_000
        samples = [{"token": make_token("sample", scene, k), "timestamp": start + 500_000 * k,
                    "prev": "", "next": "", "scene_token": scene_token} for k in range(count)]
        _link(samples)
        tables["sample"].extend(samples)
        tables["scene"].append({
            "token": scene_token, "log_token": log_token, "nbr_samples": count,
            "first_sample_token": samples[0]["token"], "last_sample_token": samples[-1]["token"],
            "name": scene, "description": f"tiny test scene {scene}",
        })
        for channel in ("CAM_FRONT", "LIDAR_TOP"):
            chain = []
            for k, sample in enumerate(samples):
                offset = -35_000 if channel == "CAM_FRONT" else 0
                if channel == "LIDAR_TOP" and k == 1:
                    # A sweep between key frames points to the following sample.
                    chain.append(_sample_data(tables, scene, channel, sample["token"],
                                              sample["timestamp"] - 250_000, key_frame=False))
                chain.append(_sample_data(tables, scene, channel, sample["token"],
                                          sample["timestamp"] + offset, key_frame=True))
            _link(chain)
        _add_instances(tables, scene_index, samples)
    return tables


def _add_instances(tables: Records, scene_index: int, samples: list[dict[str, Any]]) -> None:
    plan = ([("vehicle.car", ["vehicle.moving"], "4", 3), ("human.pedestrian.adult",
             ["pedestrian.standing"], "3", 2)] if scene_index == 0
            else [("vehicle.bicycle", [], "", 1)])
    for number, (category, attributes, visibility, count) in enumerate(plan):
        instance_token = make_token("instance", scene_index, number)
        annotations = [{
            "token": make_token("sample_annotation", scene_index, number, k),
            "sample_token": samples[k]["token"], "instance_token": instance_token,
            "visibility_token": visibility,
            "attribute_tokens": [attribute_token(name) for name in attributes],
            "translation": [20.0 + 2 * k + number, 3.0 - number, 0.9],
            "size": [1.9, 4.6, 1.7] if category == "vehicle.car" else [0.6, 0.7, 1.8],
            "rotation": [0.9238795325112867, 0.0, 0.0, 0.3826834323650898],
            "prev": "", "next": "", "num_lidar_pts": 40 - 10 * k, "num_radar_pts": k,
        } for k in range(count)]
        _link(annotations)
        tables["sample_annotation"].extend(annotations)
        tables["instance"].append({
            "token": instance_token, "category_token": category_token(category),
            "nbr_annotations": count, "first_annotation_token": annotations[0]["token"],
            "last_annotation_token": annotations[-1]["token"],
        })


def write_records(dataroot: Path, records: Records, version: str = VERSION) -> None:
    """Write ``records`` through DatasetWriter (map records through add_map)."""
    with DatasetWriter(dataroot, version) as writer:
        for table in TABLE_NAMES:
            for record in records[table]:
                if table == "map":
                    writer.add_map(record["token"], record["log_tokens"], record["category"])
                else:
                    writer.add(table, record)


@pytest.fixture
def write_dataset() -> Callable[..., None]:
    """write_dataset(dataroot, records, version="v1.0-mini"), see write_records."""
    return write_records


@pytest.fixture
def tiny_records() -> Records:
    return build_tiny_records()


@pytest.fixture
def tiny_dataroot(tmp_path: Path, tiny_records: Records) -> Path:
    dataroot = tmp_path / "nuscenes"
    write_records(dataroot, tiny_records)
    return dataroot


@pytest.fixture
def rewrite_table(tiny_dataroot: Path) -> Callable[[str, Callable[[Any], Any]], Path]:
    """rewrite_table(table, change): replace a table file of the tiny dataset by
    ``change(decoded JSON)`` (or the decoded JSON changed in place when it returns None),
    written with the json module, bypassing the writer's checks. Returns the file's path."""

    def rewrite(table: str, change: Callable[[Any], Any]) -> Path:
        path = tiny_dataroot / VERSION / f"{table}.json"
        document = json.loads(path.read_text())
        changed = change(document)
        path.write_text(json.dumps(document if changed is None else changed))
        return path

    return rewrite
