"""The CI gate's committed expectation (.ci/demo-quick-report.json): a baseline `sianms report`
reads, which passes against itself and fails on one planted regression."""

import copy
import json
from pathlib import Path

import pytest

from sianms_cli.reporting.report import DEFAULT_ALLOWANCES, compare, read_baseline

EXPECTED = Path(__file__).resolve().parents[1] / ".ci" / "demo-quick-report.json"


@pytest.fixture(scope="module")
def expected():
    return read_baseline(EXPECTED)


def regressions(now, baseline):
    comparison = compare(now, baseline, DEFAULT_ALLOWANCES)
    return [row for row in comparison["cells"] + comparison["reidentification"] if row["regressed"]]


def test_the_expected_report_is_a_quick_demo_of_the_paper_methods(expected):
    assert expected["config"]["split"] == "mini_val"
    assert {"vanilla", "axis-nms", "rotated-nms", "circle-nms", "sianms", "hybrid", "oracle"} <= set(expected["methods"])
    cell = expected["regions"]["overlap"]["sianms"][expected["table_class"]]
    assert cell["gt"] > 0 and cell["AP"] is not None
    assert regressions(expected, expected) == []


@pytest.mark.parametrize("column, change", [("AP", -0.6), ("ATE", 0.03), ("AOE", 0.03)])
def test_one_planted_regression_fails_the_gate_and_is_named(expected, column, change):
    now = copy.deepcopy(expected)
    now["regions"]["overlap"]["sianms"][expected["table_class"]][column] += change
    found = regressions(now, expected)
    assert [(row["region"], row["method"], row["metric"]) for row in found] == [("overlap", "sianms", column)]


def test_a_change_within_the_allowance_passes(expected):
    now = copy.deepcopy(expected)
    now["regions"]["all"]["vanilla"][expected["table_class"]]["AP"] -= 0.4
    now["reidentification"]["sianms"]["f1"] -= 0.04
    assert regressions(now, expected) == []


def test_the_expected_report_is_strict_json():
    json.loads(EXPECTED.read_text(), parse_constant=lambda name: pytest.fail(f"{name} in {EXPECTED}"))
