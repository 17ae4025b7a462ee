"""Cross-check of `sianms synth` and our geometry against the official nuscenes-devkit.

The devkit pins numpy<2, so it runs in its own virtual environment (built by
``scripts/devkit_venv.sh``) through ``scripts/devkit_dump.py``, which writes the facts it
computes to JSON. This module generates a small synthetic dataroot, has the devkit
dump it, and compares: the devkit loads it, reads every LIDAR_TOP file (key frames and
the sweeps between them), stacks ten sweeps per key frame with ``from_file_multisweep``
as our transform chain does, counts exactly ``num_lidar_pts`` points in every annotated
box, scores the ground truth as a perfect detector (AP 1) and projects every visible box
corner where our geometry does.

Skipped when the devkit interpreter is absent: ``.devkit-venv/bin/python`` at the
repository root, or the interpreter named by ``SIANMS_DEVKIT_PYTHON``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from devkit_venv import DEVKIT_MARKS, DEVKIT_PYTHON, REPO_ROOT

from sianms_cli.geometry.boxes import box_corners
from sianms_cli.geometry.projection import BoxVisibility, box_in_image, view_points
from sianms_cli.geometry.transforms import apply_transform, global_to_sensor, sensor_to_global
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.splits import split_scene_names

DUMP_SCRIPT = REPO_ROOT / "scripts" / "devkit_dump.py"

VERSION = "v1.0-mini"
# Two scenes of v1.0-mini are scene-0061 (mini_train) and scene-0103 (mini_val); the
# evaluation runs on the predefined mini_val split, so the devkit's own split lists and
# its strict "same samples as the split" check are exercised.
SPLIT = "mini_val"
SYNTH_ARGS = ["--version", VERSION, "--scenes", "2", "--scene-seconds", "8", "--image-scale", "0.2", "--seed", "0",
              "--quiet"]
PAPER_CLASSES = ("car", "pedestrian", "bicycle")
NSWEEPS = 10  # sweeps per key frame stacked by from_file_multisweep (the dump's default)

pytestmark = DEVKIT_MARKS


def run_checked(command: list[str], what: str, timeout: float) -> None:
    """Run a subprocess; on failure, fail the test with its output rather than a bare code."""
    result = subprocess.run(command, capture_output=True, text=True, timeout=timeout, cwd=REPO_ROOT)
    if result.returncode != 0:
        pytest.fail(f"{what} failed (exit {result.returncode}):\n{result.stdout}\n{result.stderr}")


@pytest.fixture(scope="module")
def dataroot(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 2-scene synthetic v1.0-mini dataroot written by `sianms synth`."""
    root = tmp_path_factory.mktemp("devkit_crosscheck") / "dataroot"
    run_checked([sys.executable, "-m", "sianms_cli", "synth", "--out", str(root), *SYNTH_ARGS], "sianms synth", 1800)
    return root


@pytest.fixture(scope="module")
def facts(dataroot: Path) -> dict:
    """The devkit's facts about the dataroot (scripts/devkit_dump.py in the devkit venv)."""
    out = dataroot.parent / "devkit_facts.json"
    run_checked([str(DEVKIT_PYTHON), str(DUMP_SCRIPT), str(dataroot), VERSION, str(out), "--split", SPLIT],
                "devkit_dump.py (nuscenes-devkit loading and evaluating the synthetic dataroot)", 900)
    return json.loads(out.read_text())


@pytest.fixture(scope="module")
def db(dataroot: Path) -> NuScenesDB:
    return NuScenesDB(dataroot, VERSION)


def test_devkit_loads_the_dataroot_with_our_table_counts(facts: dict, db: NuScenesDB) -> None:
    ours = {name: len(db.table(name)) for name in facts["table_counts"]}
    assert facts["table_counts"] == ours
    assert facts["table_counts"]["sample"] > 0 and facts["table_counts"]["sample_annotation"] > 0


def test_split_holds_generated_scenes(db: NuScenesDB) -> None:
    # Guards the premise of the AP test: the evaluated split is not empty.
    generated = set(db.table("scene").column("name").tolist())
    assert generated & set(split_scene_names(SPLIT, VERSION))


def test_devkit_reads_every_lidar_file(facts: dict, db: NuScenesDB) -> None:
    lidar = facts["lidar_files"]
    assert lidar["missing"] == []
    assert lidar["unreadable"] == {}
    tokens = db.table("sample_data").tokens[db.sample_data_channels() == "LIDAR_TOP"].tolist()
    assert sorted(lidar["point_counts"]) == sorted(tokens)
    for token in tokens:
        assert lidar["point_counts"][token] == len(db.read_lidar(token)), token


def test_devkit_reads_sweeps_between_key_frames(facts: dict, db: NuScenesDB) -> None:
    sweeps = ~db.table("sample_data").column("is_key_frame") & (db.sample_data_channels() == "LIDAR_TOP")
    assert sweeps.sum() == 9 * (len(db.table("sample")) - len(db.table("scene")))
    assert set(db.table("sample_data").tokens[sweeps].tolist()) <= set(facts["lidar_files"]["point_counts"])


def test_devkit_multisweep_stacks_our_sweep_chains(facts: dict, db: NuScenesDB) -> None:
    stacks = facts["multisweep"]
    assert len(stacks) == len(db.table("sample"))
    for stack in stacks:
        key = db.keyframe_data(stack["sample_token"])["LIDAR_TOP"]
        reference = db.get("sample_data", key)
        to_reference = np.linalg.inv(sensor_to_global(*db.ego_pose_of(key), *db.calibration_of(key)[:2]))
        record, lags, stacked = reference, [], []
        for _ in range(NSWEEPS):
            points = db.read_lidar(record["token"])[:, :3]
            points = points[~((np.abs(points[:, 0]) < 1.0) & (np.abs(points[:, 1]) < 1.0))]  # remove_close(1 m)
            to_global = sensor_to_global(*db.ego_pose_of(record["token"]), *db.calibration_of(record["token"])[:2])
            stacked.append(apply_transform(to_reference @ to_global, points.astype(np.float64)))
            lags.append(round((reference["timestamp"] - record["timestamp"]) * 1e-6, 6))
            if not record["prev"]:
                break
            record = db.get("sample_data", record["prev"])
        stacked = np.concatenate(stacked)
        assert stack["n_points"] == len(stacked)
        assert stack["time_lags"] == sorted(set(lags))
        np.testing.assert_allclose(stack["mean_point"], stacked.mean(axis=0), rtol=0, atol=1e-4)


def test_devkit_points_in_box_equals_num_lidar_pts(facts: dict, db: NuScenesDB) -> None:
    annotations = facts["annotation_points"]
    assert len(annotations) == len(db.table("sample_annotation"))
    mismatches = [a for a in annotations if a["points_in_box"] != a["num_lidar_pts"]]
    assert mismatches == [], f"{len(mismatches)} annotations differ, e.g. {mismatches[:3]}"


def test_devkit_scores_ground_truth_as_perfect(facts: dict) -> None:
    evaluation = facts["evaluation"]
    assert evaluation["split"] == SPLIT
    # An AP of 1 only means something for a class with boxes left after the devkit's filters;
    # a two-scene world need not hold a bicycle, but always holds cars and pedestrians.
    evaluated = [name for name in PAPER_CLASSES if evaluation["gt_boxes_per_class_evaluated"].get(name, 0) > 0]
    assert {"car", "pedestrian"} <= set(evaluated)
    for name in evaluated:
        assert evaluation["mean_dist_aps"][name] == pytest.approx(1.0, abs=1e-9), name
        for threshold, ap in evaluation["label_aps"][name].items():
            assert ap == pytest.approx(1.0, abs=1e-9), (name, threshold)
        for metric in ("trans_err", "scale_err", "orient_err"):
            assert evaluation["label_tp_errors"][name][metric] == pytest.approx(0.0, abs=1e-9), (name, metric)


def our_corners_in_camera(db: NuScenesDB, sd_token: str, annotation_tokens: list[str]) -> np.ndarray:
    """(N, 8, 3) corners of annotations in the camera frame of one sample_data, by our geometry."""
    records = [db.get("sample_annotation", token) for token in annotation_tokens]
    corners_global = box_corners(
        np.array([r["translation"] for r in records], dtype=np.float64).reshape(-1, 3),
        np.array([r["size"] for r in records], dtype=np.float64).reshape(-1, 3),
        np.array([r["rotation"] for r in records], dtype=np.float64).reshape(-1, 4),
    )
    ego_rotation, ego_translation = db.ego_pose_of(sd_token)
    sensor_rotation, sensor_translation, _ = db.calibration_of(sd_token)
    to_camera = global_to_sensor(ego_rotation, ego_translation, sensor_rotation, sensor_translation)
    return apply_transform(to_camera, corners_global.reshape(-1, 3)).reshape(-1, 8, 3)


def test_devkit_projected_corners_match_ours(facts: dict, db: NuScenesDB) -> None:
    images = facts["cameras"]
    assert len(images) == 6 * len(db.table("sample"))
    assert sum(len(image["boxes"]) for image in images) > 0
    for image in images:
        sd_token = image["sample_data_token"]
        _, _, intrinsic = db.calibration_of(sd_token)
        np.testing.assert_allclose(intrinsic, image["camera_intrinsic"], rtol=0, atol=0)

        # Same visible set: our box_in_image (ANY) over all annotations of the sample.
        all_tokens = db.get("sample", image["sample_token"])["anns"]
        all_corners = our_corners_in_camera(db, sd_token, all_tokens)
        visible = box_in_image(all_corners, intrinsic, (image["width"], image["height"]), BoxVisibility.ANY)
        devkit_tokens = [box["annotation_token"] for box in image["boxes"]]
        assert sorted(np.asarray(all_tokens)[visible].tolist()) == sorted(devkit_tokens), sd_token

        if not devkit_tokens:
            continue
        corners_cam = our_corners_in_camera(db, sd_token, devkit_tokens)
        pixels = view_points(corners_cam.reshape(-1, 3), intrinsic, normalize=True)[:, :2].reshape(-1, 8, 2)
        np.testing.assert_allclose(corners_cam, [box["corners_cam"] for box in image["boxes"]], rtol=0, atol=1e-9)
        np.testing.assert_allclose(pixels, [box["corners_img"] for box in image["boxes"]], rtol=0, atol=1e-6)
