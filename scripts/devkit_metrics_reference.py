"""Reference numbers of the official nuscenes-devkit for `sianms metrics`, and the inputs they
are computed on.

One copy of everything both sides need, importable from the tests (numpy 2, sianms) and run
by the devkit's interpreter (numpy < 2, no sianms):

- the dataroot: :func:`write_dataroot`, a small v1.0-mini dataset written in pure Python
  (two scenes with two real camera rigs, moving objects of 10 categories with prev/next
  chains, boxes beyond the class ranges or without points, bicycle racks) plus a
  ``splits.json`` with the custom splits of ``CUSTOM_SPLITS``. It does not depend on
  ``sianms synth``, so the fixture stays valid while the synthetic world evolves;
- the results files: :func:`make_results`, pure Python (``random.Random`` seeded by strings),
  so both interpreters write the same bytes: perturbed ground truth with misses, false
  positives, duplicates, equal scores, a class without predictions (truck), a class without
  ground truth (trailer), predictions beyond the class ranges, inside bicycle racks, NaN
  velocities; and an all-equal-scores file listed in a scrambled sample order;
- ``CASES``: which results file is evaluated on which split and regions.

Commands:

    python scripts/devkit_metrics_reference.py build DIR
        write the dataroot to DIR/dataroot and the results files to DIR/results/*.json
    .devkit-venv/bin/python scripts/devkit_metrics_reference.py devkit DIR OUT.json
        (devkit venv) run DetectionEval (detection_cvpr_2019) on every case and region
    python scripts/devkit_metrics_reference.py fixtures [--out FILE]
        build in a temporary folder, run the devkit step through
        .devkit-venv/bin/python (or $SIANMS_DEVKIT_PYTHON) and write the committed fixture
        (default tests/fixtures/metrics/devkit_reference.json)

Regions: the devkit has none, so the devkit step computes region membership itself, with the
devkit's own geometry (pyquaternion rotations, ``view_points``): a box is in the overlap region
when its centre, taken into the ego frame with the ego pose of the sample's LIDAR_TOP key
frame, lies in front of both cameras of a contiguous pair of the nuScenes ring and projects
inside both images (0 <= u < W, 0 <= v < H). The filtered ground truth and predictions of
``DetectionEval`` are restricted to the region before ``evaluate()``: an independent
implementation of the rule that tests/metrics compares ours with.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import random
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

VERSION = "v1.0-mini"
CUSTOM_SPLITS = {"custom_all": ["scene-0103", "scene-0061"], "custom_val": ["scene-0103"]}
MINI_VAL_SCENES = ["scene-0103", "scene-0916"]
RING = ["CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_BACK_RIGHT", "CAM_BACK", "CAM_BACK_LEFT", "CAM_FRONT_LEFT"]
PAIRS = [f"{RING[k]}|{RING[(k + 1) % len(RING)]}" for k in range(len(RING))]
REGIONS_ALL = ["all", "overlap", "non-overlap"] + [f"overlap:{pair}" for pair in PAIRS]

CASES = [
    {"name": "perturbed_mini_val", "split": "mini_val", "results": "perturbed_mini_val", "regions": REGIONS_ALL},
    {"name": "perturbed_custom_all", "split": "custom_all", "results": "perturbed_all",
     "regions": ["all", "overlap", "non-overlap"]},
    {"name": "ties_mini_val", "split": "mini_val", "results": "ties_mini_val", "regions": ["all", "overlap"]},
    {"name": "ties_custom_val", "split": "custom_val", "results": "ties_all", "regions": ["all", "overlap"]},
]
# results file -> (generator, scenes whose samples it lists, listed in a scrambled order?)
RESULTS_FILES = {
    "perturbed_mini_val": ("perturbed", ["scene-0103"], False),
    "perturbed_all": ("perturbed", ["scene-0061", "scene-0103"], False),
    "ties_mini_val": ("ties", ["scene-0103"], True),
    "ties_all": ("ties", ["scene-0061", "scene-0103"], True),
}

DETECTION = {
    "movable_object.barrier": "barrier", "vehicle.bicycle": "bicycle", "vehicle.bus.bendy": "bus",
    "vehicle.bus.rigid": "bus", "vehicle.car": "car", "vehicle.construction": "construction_vehicle",
    "vehicle.motorcycle": "motorcycle", "human.pedestrian.adult": "pedestrian",
    "human.pedestrian.child": "pedestrian", "human.pedestrian.construction_worker": "pedestrian",
    "human.pedestrian.police_officer": "pedestrian", "movable_object.trafficcone": "traffic_cone",
    "vehicle.trailer": "trailer", "vehicle.truck": "truck",
}
ATTRIBUTES = {
    "pedestrian": ["pedestrian.moving", "pedestrian.sitting_lying_down", "pedestrian.standing"],
    "bicycle": ["cycle.with_rider", "cycle.without_rider"], "motorcycle": ["cycle.with_rider", "cycle.without_rider"],
    **{name: ["vehicle.moving", "vehicle.parked", "vehicle.stopped"]
       for name in ("car", "bus", "construction_vehicle", "trailer", "truck")},
    "traffic_cone": [], "barrier": [],
}
TABLES = ["category", "attribute", "visibility", "instance", "sensor", "calibrated_sensor", "ego_pose", "log",
          "scene", "sample", "sample_data", "sample_annotation", "map"]
META = {"use_camera": True, "use_lidar": True, "use_radar": False, "use_map": False, "use_external": False}
FIXTURE = Path(__file__).resolve().parents[1] / "tests" / "fixtures" / "metrics" / "devkit_reference.json"


# --------------------------------------------------------------------------- dataroot


def _token(*parts: object) -> str:
    return hashlib.md5(json.dumps([str(p) for p in parts]).encode("utf-8")).hexdigest()


def _load(table_root: Path, name: str) -> list[dict]:
    with open(table_root / f"{name}.json", encoding="utf-8") as handle:
        return json.load(handle)


# calibrated_sensor of the six cameras and the LiDAR, two real rigs (docs/synthetic_world.md#rig, sets A and B):
# channel -> (translation, rotation w x y z, fx = fy, cx, cy).
RIGS = {
    "scene-0061": {
        "CAM_FRONT": (
            (1.70079, 0.01595, 1.51096), (0.49980, -0.50303, 0.49978, -0.49737), 1266.417, 816.267, 491.507),
        "CAM_FRONT_RIGHT": (
            (1.55085, -0.49340, 1.49575), (0.20603, -0.20269, 0.68245, -0.67136), 1260.847, 807.968, 495.334),
        "CAM_BACK_RIGHT": (
            (1.01488, -0.48057, 1.56240), (0.12281, -0.13240, -0.70043, 0.69050), 1259.514, 807.253, 501.196),
        "CAM_BACK": (
            (0.02833, 0.00345, 1.57910), (0.50379, -0.49740, -0.49419, 0.50455), 809.221, 829.220, 481.778),
        "CAM_BACK_LEFT": (
            (1.03569, 0.48480, 1.59097), (0.69242, -0.70316, -0.11648, 0.11203), 1256.741, 792.113, 492.776),
        "CAM_FRONT_LEFT": (
            (1.52388, 0.49463, 1.50933), (0.67573, -0.67363, 0.21214, -0.21123), 1272.598, 826.615, 479.752),
        "LIDAR_TOP": (
            (0.943713, 0.0, 1.84023), (0.70780, -0.00649, 0.01065, -0.70631), None, None, None),
    },
    "scene-0103": {
        "CAM_FRONT": (
            (1.72201, 0.00475, 1.49491), (0.50772, -0.49734, 0.49837, -0.49648), 1252.813, 826.588, 469.985),
        "CAM_FRONT_RIGHT": (
            (1.58083, -0.49908, 1.51749), (0.20335, -0.19146, 0.67857, -0.67936), 1256.749, 817.789, 451.954),
        "CAM_BACK_RIGHT": (
            (1.05945, -0.46720, 1.55051), (0.13819, -0.13797, -0.68933, 0.69763), 1249.963, 825.377, 462.548),
        "CAM_BACK": (
            (0.05525, 0.01079, 1.56794), (0.50680, -0.49776, -0.49878, 0.49659), 796.891, 857.777, 476.885),
        "CAM_BACK_LEFT": (
            (1.04852, 0.48306, 1.56210), (0.70486, -0.69073, -0.11209, 0.11617), 1254.986, 829.577, 467.168),
        "CAM_FRONT_LEFT": (
            (1.57526, 0.50052, 1.50696), (0.68121, -0.66875, 0.21017, -0.21108), 1257.863, 827.241, 450.915),
        "LIDAR_TOP": (
            (0.985793, 0.0, 1.84019), (0.70675, -0.01530, 0.01740, -0.70708), None, None, None),
    },
}
SCENES = {"scene-0061": 12, "scene-0103": 14}  # samples (2 Hz key frames); mini_train and mini_val
OBJECTS = {  # category -> (tracks per scene, size w l h)
    "vehicle.car": (14, (1.95, 4.62, 1.73)), "vehicle.truck": (4, (2.51, 6.93, 2.84)),
    "vehicle.bus.rigid": (2, (2.93, 11.23, 3.47)), "human.pedestrian.adult": (8, (0.67, 0.73, 1.77)),
    "human.pedestrian.child": (2, (0.51, 0.53, 1.38)), "vehicle.bicycle": (6, (0.60, 1.70, 1.28)),
    "vehicle.motorcycle": (2, (0.77, 2.11, 1.47)), "movable_object.trafficcone": (6, (0.41, 0.41, 1.07)),
    "movable_object.barrier": (6, (2.53, 0.50, 0.98)), "animal": (1, (0.5, 1.0, 0.6)),
}
CATEGORY_ATTRIBUTES = {
    "vehicle": ["vehicle.moving", "vehicle.parked", "vehicle.stopped"],
    "human": ["pedestrian.moving", "pedestrian.sitting_lying_down", "pedestrian.standing"],
    "cycle": ["cycle.with_rider", "cycle.without_rider"],
}
ALL_ATTRIBUTES = [a for names in CATEGORY_ATTRIBUTES.values() for a in names]
RACK_SIZE = [2.5, 5.0, 1.5]


def _attribute_family(category: str) -> str | None:
    if category in ("vehicle.bicycle", "vehicle.motorcycle"):
        return "cycle"
    return {"vehicle": "vehicle", "human": "human"}.get(category.split(".")[0])


def write_dataroot(dataroot: str | Path) -> Path:
    """Write the reference dataroot (tables, a map file and splits.json), pure Python.

    Two scenes of the devkit's v1.0-mini (scene-0061 in mini_train, scene-0103 in mini_val),
    each with its own real camera rig; the ego drives a curve; objects of 10 categories move
    on tracks with prev/next chains (one lone annotation per scene, so a NaN GT velocity),
    some beyond the class ranges, 15 % without LiDAR points (half of those with a radar
    point), a few with no attribute; every third bicycle sits in a ``static_object.bicycle_rack``
    box. Same bytes on every run and interpreter.
    """
    rng = random.Random("sianms metrics reference dataroot")
    root = Path(dataroot)
    table_root = root / VERSION
    table_root.mkdir(parents=True, exist_ok=True)
    tables: dict[str, list[dict]] = {name: [] for name in TABLES}
    categories = sorted({*OBJECTS, "static_object.bicycle_rack", "vehicle.trailer", "vehicle.construction"})
    for name in categories:
        tables["category"].append({"token": _token("category", name), "name": name, "description": name})
    for name in ALL_ATTRIBUTES:
        tables["attribute"].append({"token": _token("attribute", name), "name": name, "description": name})
    for level, token in (("v0-40", "1"), ("v40-60", "2"), ("v60-80", "3"), ("v80-100", "4")):
        tables["visibility"].append({"token": token, "level": level, "description": level})
    for channel in RING + ["LIDAR_TOP"]:
        tables["sensor"].append({"token": _token("sensor", channel), "channel": channel,
                                 "modality": "lidar" if channel == "LIDAR_TOP" else "camera"})
    map_token = _token("map")
    tables["map"].append({"token": map_token, "category": "semantic_prior", "filename": f"maps/{map_token}.png",
                          "log_tokens": [_token("log", scene) for scene in SCENES]})
    (root / "maps").mkdir(parents=True, exist_ok=True)
    (root / "maps" / f"{map_token}.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    for scene_index, (scene, count) in enumerate(SCENES.items()):
        _write_scene(tables, rng, scene, scene_index, count)
    for name in TABLES:
        with open(table_root / f"{name}.json", "w", encoding="utf-8") as handle:
            json.dump(tables[name], handle, indent=0)
    with open(table_root / "splits.json", "w", encoding="utf-8") as handle:
        json.dump(CUSTOM_SPLITS, handle, indent=1)
    return root


def _write_scene(tables: dict[str, list[dict]], rng: random.Random, scene: str, scene_index: int, count: int) -> None:
    log = _token("log", scene)
    tables["log"].append({"token": log, "logfile": f"reference-{scene}", "vehicle": "n015",
                          "date_captured": "2018-07-24", "location": "singapore-onenorth"})
    calibration = {}
    for channel, (translation, rotation, focal, cx, cy) in RIGS[scene].items():
        norm = math.sqrt(sum(v * v for v in rotation))
        calibration[channel] = _token("calibrated_sensor", scene, channel)
        tables["calibrated_sensor"].append({
            "token": calibration[channel], "sensor_token": _token("sensor", channel), "translation": list(translation),
            "rotation": [v / norm for v in rotation],
            "camera_intrinsic": [[focal, 0.0, cx], [0.0, focal, cy], [0.0, 0.0, 1.0]] if focal else []})
    samples = [_token("sample", scene, k) for k in range(count)]
    tables["scene"].append({"token": _token("scene", scene), "name": scene, "description": "reference",
                            "log_token": log, "nbr_samples": count, "first_sample_token": samples[0],
                            "last_sample_token": samples[-1]})
    t0 = 1_532_402_927_000_000 + scene_index * 60_000_000
    origin = (600.0 + 400.0 * scene_index, 1600.0)
    ego = []
    for k, token in enumerate(samples):
        heading = 0.4 + 0.05 * k + scene_index
        ego.append((origin[0] + 40 * math.sin(0.12 * k), origin[1] + 4.5 * k, heading))
        tables["sample"].append({"token": token, "timestamp": t0 + 500_000 * k, "prev": samples[k - 1] if k else "",
                                 "next": samples[k + 1] if k + 1 < count else "",
                                 "scene_token": _token("scene", scene)})
        pose = _token("ego_pose", scene, k)
        tables["ego_pose"].append({"token": pose, "timestamp": t0 + 500_000 * k,
                                   "rotation": [math.cos(heading / 2), 0.0, 0.0, math.sin(heading / 2)],
                                   "translation": [ego[k][0], ego[k][1], 0.0]})
        for channel in RING + ["LIDAR_TOP"]:
            camera = channel != "LIDAR_TOP"
            tables["sample_data"].append({
                "token": _token("sample_data", scene, k, channel), "sample_token": token, "ego_pose_token": pose,
                "calibrated_sensor_token": calibration[channel], "timestamp": t0 + 500_000 * k,
                "fileformat": "jpg" if camera else "pcd", "is_key_frame": True,
                "height": 900 if camera else 0, "width": 1600 if camera else 0,
                "filename": f"samples/{channel}/ref__{channel}__{t0 + 500_000 * k}.{'jpg' if camera else 'pcd.bin'}",
                "prev": "", "next": ""})
    bicycles = 0
    for category, (tracks, size) in OBJECTS.items():
        family = _attribute_family(category)
        for j in range(tracks):
            first = rng.randrange(0, count - 2)
            last = first if j == 0 and category == "vehicle.car" else rng.randrange(first + 1, count)
            radius = rng.uniform(3, 55) if rng.random() < 0.85 else rng.uniform(55, 75)
            if rng.random() < 0.4:  # near the middle of a camera-overlap sector
                angle = math.radians(rng.choice([28, -28, 83, -83, 139, -139]) + rng.uniform(-3, 3))
                radius = rng.uniform(8, 45)
            else:
                angle = rng.uniform(-math.pi, math.pi)
            speed = rng.uniform(0, 2)
            yaw = rng.uniform(-math.pi, math.pi)
            instance = _token("instance", scene, category, j)
            tokens = [_token("annotation", scene, category, j, k) for k in range(first, last + 1)]
            tables["instance"].append({"token": instance, "category_token": _token("category", category),
                                       "nbr_annotations": len(tokens), "first_annotation_token": tokens[0],
                                       "last_annotation_token": tokens[-1]})
            attribute = [] if family is None or rng.random() < 0.1 else \
                [_token("attribute", rng.choice(CATEGORY_ATTRIBUTES[family]))]
            for i, k in enumerate(range(first, last + 1)):
                # Objects keep their place around the moving ego, drifting slowly.
                ego_x, ego_y, heading = ego[k]
                x = ego_x + radius * math.cos(angle + heading) + speed * 0.5 * i * math.cos(yaw)
                y = ego_y + radius * math.sin(angle + heading) + speed * 0.5 * i * math.sin(yaw)
                lidar = 0 if rng.random() < 0.15 else rng.randrange(1, 200)
                tables["sample_annotation"].append({
                    "token": tokens[i], "sample_token": samples[k], "instance_token": instance,
                    "visibility_token": str(rng.randrange(1, 5)), "attribute_tokens": attribute,
                    "translation": [x, y, size[2] / 2], "size": list(size),
                    "rotation": [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)],
                    "prev": tokens[i - 1] if i else "", "next": tokens[i + 1] if i + 1 < len(tokens) else "",
                    "num_lidar_pts": lidar, "num_radar_pts": rng.randrange(0, 2) if lidar == 0 else 0})
                if category == "vehicle.bicycle":
                    bicycles += 1
                    if bicycles % 3 == 0:
                        _add_rack(tables, tables["sample_annotation"][-1])


def _add_rack(tables: dict[str, list[dict]], bicycle: dict) -> None:
    instance, annotation = _token("rack-instance", bicycle["token"]), _token("rack", bicycle["token"])
    tables["instance"].append({"token": instance, "category_token": _token("category", "static_object.bicycle_rack"),
                               "nbr_annotations": 1, "first_annotation_token": annotation,
                               "last_annotation_token": annotation})
    tables["sample_annotation"].append({
        "token": annotation, "sample_token": bicycle["sample_token"], "instance_token": instance,
        "visibility_token": "4", "attribute_tokens": [], "translation": list(bicycle["translation"]),
        "size": list(RACK_SIZE), "rotation": list(bicycle["rotation"]), "prev": "", "next": "",
        "num_lidar_pts": 10, "num_radar_pts": 0})


def fingerprint(dataroot: str | Path) -> str:
    """sha256 of the table files and splits.json: the fixture is valid for exactly this data."""
    digest = hashlib.sha256()
    table_root = Path(dataroot) / VERSION
    for name in TABLES + ["splits"]:
        digest.update(name.encode())
        digest.update((table_root / f"{name}.json").read_bytes())
    return digest.hexdigest()


# --------------------------------------------------------------------------- results


class _Tables:
    """What the results generator needs from the tables, read with the json module."""

    def __init__(self, dataroot: str | Path) -> None:
        table_root = Path(dataroot) / VERSION
        scenes = {s["token"]: s["name"] for s in _load(table_root, "scene")}
        self.samples = [(s["token"], scenes[s["scene_token"]]) for s in _load(table_root, "sample")]
        categories = {c["token"]: c["name"] for c in _load(table_root, "category")}
        category_of_instance = {i["token"]: categories[i["category_token"]] for i in _load(table_root, "instance")}
        attributes = {a["token"]: a["name"] for a in _load(table_root, "attribute")}
        self.gt: dict[str, list[dict]] = {}
        self.racks: dict[str, list[dict]] = {}
        for a in _load(table_root, "sample_annotation"):
            category = category_of_instance[a["instance_token"]]
            if category == "static_object.bicycle_rack":
                self.racks.setdefault(a["sample_token"], []).append(a)
            elif category in DETECTION:
                attribute = attributes[a["attribute_tokens"][0]] if a["attribute_tokens"] else ""
                self.gt.setdefault(a["sample_token"], []).append({**a, "name": DETECTION[category],
                                                                  "attribute": attribute})
        sensors = {s["token"]: s["channel"] for s in _load(table_root, "sensor")}
        channel_of_cs = {c["token"]: sensors[c["sensor_token"]] for c in _load(table_root, "calibrated_sensor")}
        poses = {p["token"]: p for p in _load(table_root, "ego_pose")}
        self.ego: dict[str, list[float]] = {}
        for sd in _load(table_root, "sample_data"):
            if sd["is_key_frame"] and channel_of_cs[sd["calibrated_sensor_token"]] == "LIDAR_TOP":
                self.ego[sd["sample_token"]] = poses[sd["ego_pose_token"]]["translation"]


def _yaw_quaternion(yaw: float) -> list[float]:
    return [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]


def _yaw_of(rotation: list[float]) -> float:
    w, x, y, z = rotation
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def _box(token: str, name: str, xyz, size, yaw: float, velocity, score: float, attribute: str) -> dict:
    return {"sample_token": token, "translation": [float(v) for v in xyz], "size": [float(v) for v in size],
            "rotation": _yaw_quaternion(yaw), "velocity": [float(v) for v in velocity], "detection_name": name,
            "detection_score": float(score), "attribute_name": attribute}


def _perturbed_boxes(tables: _Tables, token: str, equal_scores: bool) -> list[dict]:
    """Predictions for one sample, from its own seeded generator."""
    rng = random.Random(f"{'ties' if equal_scores else 'perturbed'}/{token}")

    def score() -> float:
        return 0.5 if equal_scores else round(rng.uniform(0.05, 1.0) * 20) / 20  # 0.05 steps: many ties

    def velocity() -> list[float]:
        return [math.nan, math.nan] if rng.random() < 0.05 else [rng.gauss(0, 2), rng.gauss(0, 2)]

    def attribute(name: str, truth: str) -> str:
        options = ATTRIBUTES[name]
        return truth if (rng.random() < 0.8 and truth in options) or not options else rng.choice(options)

    boxes = []
    for gt in tables.gt.get(token, []):
        name = gt["name"]
        if name == "truck" or rng.random() < 0.15:  # truck: a class with GT but no prediction; 15 % misses
            continue
        if rng.random() < 0.05:
            name = rng.choice(["car", "pedestrian", "bicycle", "barrier", "traffic_cone"])
        sigma = rng.choice([0.1, 0.3, 0.8, 1.5])
        xyz = [gt["translation"][0] + rng.gauss(0, sigma), gt["translation"][1] + rng.gauss(0, sigma),
               gt["translation"][2] + rng.gauss(0, 0.2)]
        size = [s * rng.uniform(0.8, 1.25) for s in gt["size"]]
        yaw = _yaw_of(gt["rotation"]) + rng.gauss(0, 0.3) + (math.pi if rng.random() < 0.1 else 0.0)
        first = score()
        boxes.append(_box(token, name, xyz, size, yaw, velocity(), first, attribute(name, gt["attribute"])))
        if rng.random() < 0.15:  # a duplicate of the same object, equal or lower score
            near = [v + rng.gauss(0, 0.3) for v in xyz[:2]] + [xyz[2]]
            duplicate = first if (equal_scores or rng.random() < 0.5) else round(first * rng.uniform(0.3, 1.0), 2)
            boxes.append(_box(token, name, near, size, yaw, velocity(), duplicate, attribute(name, gt["attribute"])))
    ego = tables.ego[token]
    for _ in range(rng.randrange(0, 6)):  # false positives, some beyond every class range
        name = rng.choice(["car", "bus", "trailer", "pedestrian", "bicycle", "motorcycle", "traffic_cone"])
        radius, angle = rng.uniform(2, 60), rng.uniform(-math.pi, math.pi)
        xyz = [ego[0] + radius * math.cos(angle), ego[1] + radius * math.sin(angle), 1.0]
        boxes.append(_box(token, name, xyz, [1.8, 4.2, 1.6], rng.uniform(-3, 3), velocity(), score(),
                          rng.choice(ATTRIBUTES[name]) if ATTRIBUTES[name] else ""))
    for rack in tables.racks.get(token, []):  # on a rack: a motorcycle (dropped) and a car (kept)
        for name in ("motorcycle", "car"):
            xyz = [rack["translation"][0] + 0.2, rack["translation"][1] - 0.3, rack["translation"][2]]
            boxes.append(_box(token, name, xyz, [0.8, 2.0, 1.4], 0.3, [0.0, 0.0], score(), ""))
    return boxes


def make_results(dataroot: str | Path, results_file: str) -> dict:
    """The submission ``results_file`` (a key of ``RESULTS_FILES``) as a JSON-ready dict."""
    generator, scenes, scrambled = RESULTS_FILES[results_file]
    tables = _Tables(dataroot)
    tokens = [token for token, scene in tables.samples if scene in scenes]
    if scrambled:
        random.Random(f"{generator}/order").shuffle(tokens)
    results = {token: _perturbed_boxes(tables, token, generator == "ties") for token in tokens}
    return {"meta": dict(META), "results": results}


def build(folder: str | Path) -> Path:
    """Write the dataroot to ``folder``/dataroot and every results file to ``folder``/results;
    returns the dataroot. Pure Python: runs in either venv."""
    folder = Path(folder)
    dataroot = write_dataroot(folder / "dataroot")
    (folder / "results").mkdir(exist_ok=True)
    for name in RESULTS_FILES:
        with open(folder / "results" / f"{name}.json", "w", encoding="utf-8") as handle:
            json.dump(make_results(dataroot, name), handle)
    return dataroot


# --------------------------------------------------------------------------- devkit side


def _finite_or_none(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: _finite_or_none(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_none(item) for item in value]
    return value


def _devkit_regions(nusc, boxes) -> dict[str, set[int]]:
    """Per region, the indices (into ``boxes``, a list of DetectionBox) of the boxes in it."""
    import numpy as np
    from nuscenes.utils.geometry_utils import view_points
    from pyquaternion import Quaternion

    members: dict[str, set[int]] = {region: set() for region in REGIONS_ALL}
    for index, box in enumerate(boxes):
        sample = nusc.get("sample", box.sample_token)
        pose = nusc.get("ego_pose", nusc.get("sample_data", sample["data"]["LIDAR_TOP"])["ego_pose_token"])
        center_ego = Quaternion(pose["rotation"]).inverse.rotate(
            np.array(box.translation) - np.array(pose["translation"]))
        seen = {}
        for channel in RING:
            sd = nusc.get("sample_data", sample["data"][channel])
            cs = nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])
            center_cam = Quaternion(cs["rotation"]).inverse.rotate(center_ego - np.array(cs["translation"]))
            if center_cam[2] <= 0:
                seen[channel] = False
                continue
            u, v = view_points(center_cam.reshape(3, 1), np.array(cs["camera_intrinsic"]), normalize=True)[:2, 0]
            seen[channel] = bool(0 <= u < sd["width"] and 0 <= v < sd["height"])
        pairs = [pair for pair in PAIRS if all(seen[c] for c in pair.split("|"))]
        members["all"].add(index)
        members["overlap" if pairs else "non-overlap"].add(index)
        for pair in pairs:
            members[f"overlap:{pair}"].add(index)
    return members


def devkit_reference(folder: str | Path) -> dict:
    """Run DetectionEval on every case and region of ``folder`` (written by :func:`build`)."""
    os.environ.setdefault("TQDM_DISABLE", "1")
    import importlib.metadata

    import numpy as np
    from nuscenes import NuScenes
    from nuscenes.eval.common.config import config_factory
    from nuscenes.eval.detection.evaluate import DetectionEval

    folder = Path(folder)
    dataroot = folder / "dataroot"
    nusc = NuScenes(version=VERSION, dataroot=str(dataroot), verbose=False)
    cases = {}
    for case in CASES:
        with tempfile.TemporaryDirectory() as out:
            evaluator = DetectionEval(nusc, config_factory("detection_cvpr_2019"),
                                      str(folder / "results" / f"{case['results']}.json"), eval_set=case["split"],
                                      output_dir=out, verbose=False)
        gt_all, pred_all = dict(evaluator.gt_boxes.boxes), dict(evaluator.pred_boxes.boxes)
        gt_list = [box for boxes in gt_all.values() for box in boxes]
        pred_list = [box for boxes in pred_all.values() for box in boxes]
        gt_regions, pred_regions = _devkit_regions(nusc, gt_list), _devkit_regions(nusc, pred_list)
        regions = {}
        for region in case["regions"]:
            for all_boxes, chosen, eval_boxes in ((gt_all, gt_regions[region], evaluator.gt_boxes),
                                                  (pred_all, pred_regions[region], evaluator.pred_boxes)):
                flat = 0
                for token, boxes in all_boxes.items():
                    eval_boxes.boxes[token] = [b for k, b in enumerate(boxes, start=flat) if k in chosen]
                    flat += len(boxes)
            metrics, _ = evaluator.evaluate()
            summary = metrics.serialize()
            regions[region] = {
                **{key: summary[key] for key in ("label_aps", "mean_dist_aps", "mean_ap", "label_tp_errors",
                                                 "tp_errors", "tp_scores", "nd_score")},
                "boxes": {"gt": sum(len(v) for v in evaluator.gt_boxes.boxes.values()),
                          "pred": sum(len(v) for v in evaluator.pred_boxes.boxes.values())},
            }
        cases[case["name"]] = {"split": case["split"], "results": case["results"], "regions": regions}
    return _finite_or_none({
        "fingerprint": fingerprint(dataroot),
        "devkit_version": importlib.metadata.version("nuscenes-devkit"),
        "numpy_version": np.__version__,
        "config": "detection_cvpr_2019",
        "cases": cases,
    })


def devkit_python() -> Path:
    """The devkit venv's interpreter: $SIANMS_DEVKIT_PYTHON or <repo>/.devkit-venv/bin/python."""
    repo = Path(__file__).resolve().parents[1]
    return Path(os.environ.get("SIANMS_DEVKIT_PYTHON") or repo / ".devkit-venv" / "bin" / "python")


def run_devkit(folder: str | Path, out: str | Path, timeout: float = 1800) -> dict:
    """Run the devkit step in the devkit venv (subprocess) and return its JSON."""
    command = [str(devkit_python()), str(Path(__file__).resolve()), "devkit", str(folder), str(out)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
    if done.returncode != 0:
        raise RuntimeError(f"devkit step failed (exit {done.returncode}):\n{done.stdout}\n{done.stderr}")
    with open(out, encoding="utf-8") as handle:
        return json.load(handle)


def _write_json(path: str | Path, payload: Any) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".partial")
    os.chmod(temp, 0o644)
    with os.fdopen(handle, "w", encoding="utf-8") as stream:
        json.dump(payload, stream, indent=1, sort_keys=False, allow_nan=False)
        stream.write("\n")
    os.replace(temp, path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    build_cmd = commands.add_parser("build", help="write the dataroot and the results files")
    build_cmd.add_argument("folder")
    devkit_cmd = commands.add_parser("devkit", help="run the devkit on a built folder (devkit venv)")
    devkit_cmd.add_argument("folder")
    devkit_cmd.add_argument("out")
    fixtures_cmd = commands.add_parser("fixtures", help="build, run the devkit, write the committed fixture")
    fixtures_cmd.add_argument("--out", default=str(FIXTURE))
    args = parser.parse_args(argv)
    if args.command == "build":
        print(build(args.folder))
    elif args.command == "devkit":
        _write_json(args.out, devkit_reference(args.folder))
    else:
        with tempfile.TemporaryDirectory(prefix="sianms_metrics_reference_") as folder:
            build(folder)
            reference = run_devkit(folder, Path(folder) / "devkit.json")
        _write_json(args.out, reference)
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
