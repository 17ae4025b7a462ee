"""scripts/match_geometry.py: where siaNMS's right and wrong matches put their two single-camera boxes."""

import importlib.util
import sys
from pathlib import Path

import pytest

from box_rows import all_boxes

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "match_geometry.py"
spec = importlib.util.spec_from_file_location("match_geometry", SCRIPT)
match_geometry = sys.modules["match_geometry"] = importlib.util.module_from_spec(spec)
spec.loader.exec_module(match_geometry)


def test_right_and_wrong_matches_by_overlap_and_centre_distance():
    boxes = all_boxes([
        ("single", "a1", "", False, False, (10.0, 0.0)), ("single", "b1", "", False, False, (10.0, 0.6)),
        ("single", "a2", "", False, False, (20.0, 0.0)), ("single", "b2", "", False, False, (23.0, 4.0)),
        ("single", "a3", "", False, False, (30.0, 0.0)), ("single", "b3", "", False, False, (36.0, 0.0)),
        ("single", "a4", "", False, False, (40.0, 0.0)), ("single", "b4", "", False, False, (40.0, 0.1)),
        ("sianms", "a1", "b1", False, True, (10.0, 0.3)),  # right, 0.6 m apart, overlapping
        ("sianms", "a2", "b2", False, True, (21.5, 2.0)),  # right, 5 m apart, not overlapping
        ("sianms", "a3", "b3", False, False, (33.0, 0.0)),  # wrong, a car length and more apart
        ("sianms", "a4", "b4", True, False, (40.0, 0.0)),  # dismissed by the frustum test: left out
        ("sianms", "a1", "b9", False, False, (10.0, 0.0)),  # b9 has no single box: left out
    ])
    figures = match_geometry.match_geometry(boxes)
    assert figures["right"]["count"] == 2 and figures["right"]["overlapping"] == 0.5
    assert figures["right"]["median_m"] == pytest.approx((0.6 + 5.0) / 2)
    assert figures["wrong"] == {"count": 1, "overlapping": 0.0, "median_m": 6.0, "p10_m": 6.0, "p90_m": 6.0}


def test_a_folder_that_is_not_a_finished_demo_is_one_error_line(tmp_path):
    import subprocess

    result = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path)], capture_output=True, text=True)
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr == f"error: {tmp_path / 'demo.json'}: file not found\n"
    (tmp_path / "demo.json").write_text('{"complete": false}')
    (tmp_path / "eval").mkdir()
    (tmp_path / "eval" / "eval.json").write_text('{"complete": false}')
    result = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path)], capture_output=True, text=True)
    assert result.returncode == 2 and result.stderr.startswith(f"error: {tmp_path}: not a finished `sianms demo`")
