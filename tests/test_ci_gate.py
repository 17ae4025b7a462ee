"""The CI gate's committed expectations, one per numeric platform (.ci/demo-quick-report.<CPU
maker>.<kernels>.json, as .ci/platform names it): baselines `sianms report` reads,
each of which passes against itself and fails on one planted regression."""

import copy
import json
from pathlib import Path

import pytest

from sianms_cli.reporting.report import DEFAULT_ALLOWANCES, compare, read_baseline

CI = Path(__file__).resolve().parents[1] / ".ci"
BASELINES = sorted(CI.glob("demo-quick-report*.json"))


@pytest.fixture(scope="module", params=BASELINES, ids=[path.name for path in BASELINES])
def baseline_path(request):
    return request.param


@pytest.fixture(scope="module")
def expected(baseline_path):
    return read_baseline(baseline_path)


def test_every_baseline_is_named_by_its_platform():
    assert [path.name for path in BASELINES] == ["demo-quick-report.AuthenticAMD.AVX2.json"]


def test_the_baselines_of_one_kind_of_kernels_share_the_dataset_and_cache(baseline_path, expected):
    # Only the trainings differ between CPU makers; the dataset differs between AVX-512 and AVX2 kernels.
    capability = baseline_path.name.split(".")[-2]
    for other in CI.glob(f"demo-quick-report.*.{capability}.json"):
        other_report = read_baseline(other)
        assert expected["config"]["dataset_sha256"] == other_report["config"]["dataset_sha256"]
        assert expected["fingerprints"]["cache_sha256"] == other_report["fingerprints"]["cache_sha256"]


def regressions(now, baseline):
    comparison = compare(now, baseline, DEFAULT_ALLOWANCES)
    return [row for row in comparison["cells"] + comparison["reidentification"] if row["regressed"]]


def test_the_expected_report_is_a_quick_demo_of_the_paper_methods(expected):
    assert expected["config"]["split"] == "mini_val"
    methods = {"vanilla", "axis-nms", "rotated-nms", "circle-nms", "sianms", "hybrid", "oracle"}
    assert methods <= set(expected["methods"])
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


def test_the_expected_report_is_strict_json(baseline_path):
    json.loads(baseline_path.read_text(), parse_constant=lambda name: pytest.fail(f"{name} in {baseline_path}"))
