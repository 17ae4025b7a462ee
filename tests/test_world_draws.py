"""scripts/world_draws.py: the world's targets over several `sianms info` files (draws of the world)."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import pytest

from sianms_cli.reporting.dataset_summary import InfoConfig, run as run_info

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "world_draws.py"


@pytest.fixture(scope="module")
def two_draws(tiny_dataroot, tmp_path_factory):
    """The tiny dataroot's `sianms info --out` JSON (sweep files read) and a copy with other barrier
    counts and no sweep files, as a tables-only draw has."""
    folder = tmp_path_factory.mktemp("draws")
    first = run_info(InfoConfig(str(tiny_dataroot)), folder / "first.json")
    second = copy.deepcopy(json.loads(json.dumps(first)))
    first_barriers = first["objects_per_keyframe_by_class"]["barrier"]
    second["objects_per_keyframe_by_class"]["barrier"] = 6.0
    second["lidar_points_per_sweep"] = None
    second["synth_marker"]["config"]["seed"] = 99
    (folder / "second.json").write_text(json.dumps(second))
    result = subprocess.run([sys.executable, str(SCRIPT), str(folder / "first.json"), str(folder / "second.json")],
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    cells = [[cell.strip() for cell in line.strip().strip("|").split("|")] for line in result.stdout.splitlines()]
    rows = {row[0]: row for row in cells}
    return first, first_barriers, rows


def test_each_draw_is_a_column_named_by_its_seed(two_draws):
    assert two_draws[2]["figure"][1:4] == ["seed 3", "seed 99", "mean ± sd"]


def test_a_row_holds_each_draw_their_mean_and_sample_sd_and_whether_the_mean_meets_the_target(two_draws):
    _, first_barriers, rows = two_draws
    mean = (first_barriers + 6.0) / 2
    sd = abs(first_barriers - 6.0) / 2 ** 0.5
    assert rows["barrier per key frame"][1:7] == [
        f"{first_barriers:.2f}", "6.00", f"{mean:.2f} ± {sd:.2f}", "4.45 (trainval)", "3.56–5.34",
        "yes" if 3.56 <= mean <= 5.34 else "no"]


def test_a_figure_one_draw_lacks_is_a_dash_and_the_mean_is_of_the_others(two_draws):
    first, _, rows = two_draws
    points = first["lidar_points_per_sweep"]["mean"]
    assert rows["LiDAR points per sweep file"][1:4] == [f"{points:,.0f}", "—", f"{points:,.0f}"]
    assert rows["LiDAR points per sweep file"][6] == ("yes" if 30_000 <= points <= 38_000 else "no")


def test_shares_print_as_percentages_against_their_bounds(two_draws):
    first, _, rows = two_draws
    share = first["image_boxes"]["share_imaged_by_2_or_more"]
    assert rows["3-D boxes imaged by ≥ 2 cameras"][1] == f"{100 * share:.1f}"
    assert rows["3-D boxes imaged by ≥ 2 cameras"][5] == "≥ 20.0 %"
    assert rows["cars heading within 5° of the ego's axes"][5] == "≤ 65.0 %"
