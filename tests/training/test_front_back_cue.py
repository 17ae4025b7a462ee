"""scripts/front_back_cue.py: cars' object points in their box's frame, and the classifier's figures."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sianms_cli.data.frustum_dataset import ShardFrustums

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "front_back_cue.py"
spec = importlib.util.spec_from_file_location("front_back_cue", SCRIPT)
front_back_cue = sys.modules["front_back_cue"] = importlib.util.module_from_spec(spec)
spec.loader.exec_module(front_back_cue)


def shard_of(boxes, box_frame_points, classes, labels):
    """Frustums whose points are ``box_frame_points[i]`` (x along, y down, z across, scaled) in box i's frame."""
    rows, offsets = [], [0]
    for (center, heading, lwh), points in zip(boxes, box_frame_points):
        along, down, across = points[:, 0] * lwh[0], points[:, 1] * lwh[2], points[:, 2] * lwh[1]
        cos, sin = np.cos(heading), np.sin(heading)  # R_y(heading), as box_corners turns a box
        xyz = np.stack([cos * along + sin * across, down, -sin * along + cos * across], 1) + center
        rows.append(np.column_stack([xyz, points[:, 3]]))
        offsets.append(offsets[-1] + len(points))
    count = len(boxes)
    return ShardFrustums(
        offsets=np.array(offsets), points=np.concatenate(rows).astype(np.float32), labels=np.concatenate(labels),
        center=np.array([b[0] for b in boxes], float), heading=np.array([b[1] for b in boxes], float),
        lwh=np.array([b[2] for b in boxes], float), class_index=np.array(classes), score=np.ones(count, np.float32),
        rot_angle=np.zeros(count), detection_id=np.array([str(i) for i in range(count)], object),
        union=np.zeros(count, bool))


def test_object_points_come_back_in_their_box_frame_scaled_by_its_size():
    rng = np.random.default_rng(3)
    points = [rng.uniform(-0.5, 0.5, (5, 4)) for _ in range(4)]
    boxes = [((4.0, 1.0, 20.0), 0.7, (4.5, 1.9, 1.6)), ((-3.0, 0.5, 12.0), -2.9, (4.0, 1.8, 1.5)),
             ((1.0, 1.0, 30.0), 1.0, (0.8, 0.7, 1.8)), ((0.0, 1.0, 8.0), 3.1, (4.2, 1.8, 1.5))]
    labels = [np.ones(5, np.int64), np.array([1, 0, 1, 1, 0]), np.ones(5, np.int64), np.zeros(5, np.int64)]
    shard = shard_of(boxes, points, [0, 0, 1, 0], labels)  # a pedestrian, and a car with no object point

    got, ranges, without = front_back_cue.box_frame_points(shard, 64, rng)
    assert got.shape == (2, 64, 4) and without == 1
    for car, (source, label) in enumerate([(points[0], labels[0]), (points[1], labels[1])]):
        apart = np.abs(got[car][:, None, :] - source[label == 1][None]).max(axis=2)
        assert (apart.min(axis=1) < 1e-5).all()  # every drawn point is one of the car's object points
        assert (apart.min(axis=0) < 1e-5).all()  # 64 draws of 5 or 3 points reach every one
    assert ranges == pytest.approx([np.hypot(4.0, 20.0), np.hypot(-3.0, 12.0)])


def test_the_classifier_finds_a_cue_a_turn_would_reverse():
    rng = np.random.default_rng(0)
    cars = rng.uniform(-0.5, 0.5, (400, 32, 4)).astype(np.float32)
    cars[:, :, 1] -= 0.3 * (cars[:, :, 0] > 0)  # the front half higher: the cue
    turned = rng.integers(0, 2, 400)
    cars[turned == 1, :, 0] *= -1
    cars[turned == 1, :, 2] *= -1
    import torch

    torch.manual_seed(0)
    model = front_back_cue.TurnClassifier()
    optimiser = torch.optim.Adam(model.parameters(), lr=1e-3)
    x, y = torch.from_numpy(cars), torch.from_numpy(turned).float()
    for _ in range(6):
        front_back_cue.train_epoch(model, optimiser, x[:300], y[:300], torch.Generator().manual_seed(0))
    shares = front_back_cue.right_by_range(model, x[300:], turned[300:], np.full(100, 20.0))
    assert shares["all"] > 0.9 and shares["15-30 m"] == shares["all"] and np.isnan(shares["0-15 m"])


def test_a_cache_that_is_not_there_is_one_error_line(tmp_path):
    result = subprocess.run([sys.executable, str(SCRIPT), "--train-cache", str(tmp_path / "none"),
                             "--held-out-cache", str(tmp_path / "none"), "--out", str(tmp_path / "f.json")],
                            capture_output=True, text=True)
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr.startswith("error: ") and str(tmp_path / "none") in result.stderr
    assert result.stderr.count("\n") == 1 and not (tmp_path / "f.json").exists()


def test_figures_on_tiny_caches_round_trip_through_the_file(tmp_path, tiny_caches):
    out = tmp_path / "cue.json"
    subprocess.run([sys.executable, str(SCRIPT), "--train-cache", str(tiny_caches[0]), "--held-out-cache",
                    str(tiny_caches[1]), "--out", str(out), "--epochs", "2", "--points", "16"],
                   check=True, capture_output=True)
    figures = json.loads(out.read_text())
    assert figures["held_out_cars"] > 0 and [row["epoch"] for row in figures["curve"]] == [1, 2]
    assert figures["right"] == figures["curve"][-1] and 0.0 <= figures["right"]["all"] <= 1.0
