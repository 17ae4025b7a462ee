"""scripts/union_box_errors.py: a union box and its two halves, each matched to the nearest ground-truth car within
2 m, compared on the pairs where all three reach the same car."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sianms_cli.errors import SianmsError
from sianms_cli.evaluation.methods import AllBoxes

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "union_box_errors.py"
spec = importlib.util.spec_from_file_location("union_box_errors", SCRIPT)
union_box_errors = sys.modules["union_box_errors"] = importlib.util.module_from_spec(spec)
spec.loader.exec_module(union_box_errors)

# Ground-truth cars: two in sample 0, one in sample 1 (x, y, yaw).
TRUTH_SAMPLE = np.array([0, 0, 1])
TRUTH_XY = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 0.0]])
TRUTH_YAW = np.array([0.0, 0.0, np.pi / 2])

# (kind, detection a, detection b, sample, x, y, yaw)
BOXES = [
    ("single", "d1", "", 0, 0.3, 0.0, 0.0),
    ("single", "d2", "", 0, 0.6, 0.0, np.pi),  # turned front to back
    ("single", "d3", "", 1, 0.0, 0.1, np.pi / 2),
    ("single", "d4", "", 1, 0.0, 3.0, np.pi / 2),  # 3 m from the car: reaches none
    ("single", "d5", "", 0, 10.2, 0.0, 0.0),
    ("oracle", "d1", "d2", 0, 0.1, 0.0, 0.0),
    ("oracle", "d3", "d4", 1, 0.0, 0.2, np.pi / 2),  # its half d4 reaches no car: not scored
]


def all_boxes(rows=BOXES) -> AllBoxes:
    count = len(rows)
    kind, a, b, sample, x, y, yaw = (np.array(column) for column in zip(*rows))
    return AllBoxes(sample=sample.astype(np.int64), kind=kind, detection_a=a, detection_b=b,
                    classes=np.full(count, "car"), score=np.full(count, 0.9),
                    translation=np.stack([x.astype(float), y.astype(float), np.zeros(count)], axis=1),
                    size=np.tile([1.9, 4.5, 1.5], (count, 1)), yaw=yaw.astype(float),
                    dismissed=np.zeros(count, bool), correct=kind == "oracle", wedges=np.full((count, 12), np.nan))


def test_each_box_reaches_the_nearest_car_of_its_own_sample_within_two_metres():
    sample = np.array([0, 0, 1, 1, 0])
    xy = np.array([[9.0, 0.5], [1.0, 0.0], [1.9, 0.0], [2.1, 0.0], [5.0, 0.0]])
    nearest = union_box_errors.nearest_truth(sample, xy, TRUTH_SAMPLE, TRUTH_XY)
    assert nearest.tolist() == [1, 0, 2, -1, -1]


def test_a_union_and_its_halves_are_scored_where_all_three_reach_one_car():
    boxes = all_boxes()
    pairs = union_box_errors.scored_pairs(boxes, TRUTH_SAMPLE, TRUTH_XY)
    assert pairs["rows"].tolist() == [[5, 6], [0, 2], [1, 3]]
    assert pairs["truth"].tolist() == [[0, 2], [0, 2], [0, -1]] and pairs["same"].tolist() == [True, False]
    kept = pairs["same"]
    figures = union_box_errors.pair_figures(boxes, pairs["rows"][:, kept], pairs["truth"][:, kept], TRUTH_XY,
                                            TRUTH_YAW)
    assert figures == pytest.approx({
        "union_centre_error": 0.1, "halves_centre_error": 0.45, "better_half_centre_error": 0.3,
        "union_below_both_halves": 1.0, "union_heading_error": 0.0, "halves_heading_error": np.pi / 2,
        "union_turned": 0.0, "halves_turned": 0.5})


def test_a_match_whose_detection_has_no_single_box_is_refused():
    with pytest.raises(SianmsError, match="a match's detection 'd3' has no single-camera box"):
        union_box_errors.union_rows(all_boxes([row for row in BOXES if row[1] != "d3" or row[0] != "single"]))


def figures_file(path, seed, union_centre_errors):
    path.write_text(json.dumps([{"eval": f"/s{seed}/{name}", "seed": seed, "scored": 100,
                                 **dict.fromkeys(union_box_errors.FIGURES, 0.5), "union_centre_error": error}
                                for name, error in zip(("eval-val", "eval-val-other"), union_centre_errors)]))
    return path


def test_the_summary_gives_each_arm_over_the_worlds_and_their_paired_difference(tmp_path):
    files = [figures_file(tmp_path / "a.json", 1, (0.30, 0.25)), figures_file(tmp_path / "b.json", 2, (0.20, 0.17))]
    result = subprocess.run([sys.executable, str(SCRIPT), "--summarize", *map(str, files)], capture_output=True,
                            text=True)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == "2 worlds (seeds 1, 2); pairs scored per world: 100, 100"
    assert lines[4].startswith("| eval-val | 0.250 ± 0.071 | 0.500 ± 0.000 |")
    # differences -0.05 and -0.03: mean -0.04, sd 0.0141, half-width 12.706 * 0.0141 / sqrt(2) = 0.127
    assert lines[6].startswith("| eval-val-other − eval-val | -0.040 ± 0.014 [-0.167, +0.087] |")


def test_missing_arguments_are_one_error_line():
    result = subprocess.run([sys.executable, str(SCRIPT), "--version", "v1.0-mini"], capture_output=True, text=True)
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr == ("error: --dataroot, --version, --split and at least one EVAL are needed (or "
                             "--summarize)\n")
