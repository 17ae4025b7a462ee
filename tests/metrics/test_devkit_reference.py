"""`sianms metrics` against the official nuscenes-devkit, number for number.

The committed fixture tests/fixtures/metrics/devkit_reference.json holds the devkit's numbers
(every AP at every threshold, every TP error, the means, mAP and NDS, and box counts) for the
cases of scripts/devkit_metrics_reference.py, which also writes the dataroot and results files
rebuilt here. The opt-in ``devkit`` test reruns the devkit itself.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from devkit_venv import needs_devkit
from metrics_reference import reference_script
from sianms_cli.metrics import evaluate, load_config, read_results

SUMMARY_KEYS = ("label_aps", "mean_dist_aps", "mean_ap", "label_tp_errors", "tp_errors", "tp_scores", "nd_score")
TOLERANCE = 1e-9


def _compare(ours, theirs, path: str, out: list) -> None:
    """Append (path, ours, theirs) for every number that differs by more than TOLERANCE."""
    if isinstance(theirs, dict):
        assert set(ours) == set(theirs), path
        for key in theirs:
            _compare(ours[key], theirs[key], f"{path}/{key}", out)
        return
    out.append(None)  # one number compared
    if theirs is None:
        if not (ours is None or math.isnan(ours)):
            out.append((path, ours, theirs))
    elif ours is None or not abs(ours - theirs) <= TOLERANCE:
        out.append((path, ours, theirs))


@pytest.fixture(scope="module")
def our_reports(reference_folder, reference_db):
    reports = {}
    for case in reference_script.CASES:
        results = read_results(reference_folder / "results" / f"{case['results']}.json")
        reports[case["name"]] = evaluate(reference_db, case["split"], results, "detection_cvpr_2019", case["regions"])
    return reports


def _check_against(reference: dict, reports: dict) -> int:
    compared, problems = 0, []
    for case in reference_script.CASES:
        for region, theirs in reference["cases"][case["name"]]["regions"].items():
            ours = reports[case["name"]].regions[region]
            out: list = []
            for key in SUMMARY_KEYS:
                _compare(getattr(ours, key), theirs[key], f"{case['name']}/{region}/{key}", out)
            compared += out.count(None)
            problems += [p for p in out if p is not None]
            assert (sum(ours.gt_counts.values()), sum(ours.pred_counts.values())) == \
                (theirs["boxes"]["gt"], theirs["boxes"]["pred"]), (case["name"], region)
    assert problems == []
    return compared


def test_every_number_equals_the_devkits(devkit_fixture, our_reports, reference_folder):
    # The fixture's fingerprint is of the tables it was made from. Another numpy or CPU may write
    # them otherwise in the last digits (an H200 machine's Python 3.12 and numpy 2.5 did) with
    # every number still equal, so a changed fingerprint is reported only beside a difference.
    if devkit_fixture["fingerprint"] != reference_script.fingerprint(reference_folder / "dataroot"):
        try:
            _check_against(devkit_fixture, our_reports)
        except AssertionError as error:
            raise AssertionError(f"the synthetic dataroot changed since tests/fixtures/metrics/devkit_reference.json "
                                 f"was made; regenerate it: python scripts/devkit_metrics_reference.py fixtures\n"
                                 f"{error}") from None
    compared = _check_against(devkit_fixture, our_reports)
    # 4 cases, 15 regions, 10 classes x (4 APs + AP + 5 TP errors) + 5 + 5 + 2 means.
    assert compared >= 1700


def test_cases_exercise_what_they_claim(our_reports):
    report = our_reports["perturbed_custom_all"]
    assert report.gt_filter.without_points > 0 and report.gt_filter.in_bicycle_rack > 0
    assert report.pred_filter.in_bicycle_rack > 0 and report.pred_filter.out_of_range > 0
    assert report.pred_filter.without_points == 0  # predictions are never dropped for points
    summary = report.regions["all"]
    assert summary.gt_counts["trailer"] == 0 and summary.pred_counts["trailer"] > 0  # a class without GT
    assert summary.gt_counts["truck"] > 0 and summary.pred_counts["truck"] == 0  # a class without predictions
    assert summary.mean_dist_aps["trailer"] == 0.0 and summary.label_tp_errors["truck"]["trans_err"] == 1.0
    assert 0 < summary.mean_dist_aps["car"] < 1
    assert math.isnan(summary.label_tp_errors["traffic_cone"]["orient_err"])
    assert 0 < sum(report.regions["overlap"].gt_counts.values()) < sum(summary.gt_counts.values())


def test_flattened_order_decides_equal_scores(our_reports, devkit_fixture):
    # Same samples, same boxes, all scores 0.5: the predefined split flattens in results-file
    # order (scrambled), the custom split in sample order; the devkit's numbers differ, so do ours.
    predefined = our_reports["ties_mini_val"].regions["all"].nd_score
    custom = our_reports["ties_custom_val"].regions["all"].nd_score
    assert predefined != pytest.approx(custom, abs=1e-6)
    assert our_reports["ties_custom_val"].ignored_samples > 0
    reference = devkit_fixture["cases"]
    assert reference["ties_mini_val"]["regions"]["all"]["nd_score"] == pytest.approx(predefined, abs=TOLERANCE)
    assert reference["ties_custom_val"]["regions"]["all"]["nd_score"] == pytest.approx(custom, abs=TOLERANCE)


def test_paper_config_is_the_devkits_numbers_on_three_classes(devkit_fixture, reference_folder, reference_db):
    # The devkit cannot run a 3-class config; per class nothing changes, the means are over 3.
    case = reference_script.CASES[0]
    results = read_results(reference_folder / "results" / f"{case['results']}.json")
    report = evaluate(reference_db, case["split"], results, "paper", ["all", "overlap"])
    config = load_config("paper")
    for region in ("all", "overlap"):
        theirs = devkit_fixture["cases"][case["name"]]["regions"][region]
        ours = report.regions[region].summary()
        assert list(ours["label_aps"]) == ["car", "pedestrian", "bicycle"]
        for name in config.class_names:
            for key in ("label_aps", "label_tp_errors"):
                for field, value in theirs[key][name].items():
                    assert ours[key][name][field] == pytest.approx(value, abs=TOLERANCE)
        mean_ap = np.mean([theirs["mean_dist_aps"][name] for name in config.class_names])
        assert ours["mean_ap"] == pytest.approx(mean_ap, abs=TOLERANCE)
        for metric, error in ours["tp_errors"].items():
            expected = np.nanmean([theirs["label_tp_errors"][n][metric] for n in config.class_names])
            assert error == pytest.approx(expected, abs=TOLERANCE)
        scores = [max(0.0, 1 - e) for e in ours["tp_errors"].values()]
        assert ours["nd_score"] == pytest.approx((5 * ours["mean_ap"] + sum(scores)) / 10, abs=TOLERANCE)


@pytest.mark.devkit
@needs_devkit
def test_live_devkit_cross_check(reference_folder, our_reports, tmp_path):
    """Rerun the devkit on the rebuilt inputs: the fixture is reproducible, and ours equals it."""
    live = reference_script.run_devkit(reference_folder, tmp_path / "devkit.json", timeout=1800)
    committed = json.loads(reference_script.FIXTURE.read_text())
    # Reproducible to the last bits that a numpy release may round differently, not bit for bit.
    live_leaves, committed_leaves = _leaves(live["cases"]), _leaves(committed["cases"])
    assert live_leaves.keys() == committed_leaves.keys()
    numbers = [key for key, value in committed_leaves.items() if isinstance(value, (int, float))]
    assert {key: live_leaves[key] for key in numbers} == pytest.approx(
        {key: committed_leaves[key] for key in numbers}, rel=1e-12, abs=1e-15, nan_ok=True)
    assert {k: v for k, v in live_leaves.items() if k not in numbers} == {
        k: v for k, v in committed_leaves.items() if k not in numbers}
    assert _check_against(live, our_reports) >= 1700


def _leaves(tree, path=""):
    """{path: value} of every number and string in a nested JSON value, for approximate equality."""
    if isinstance(tree, dict):
        return {key: value for name, child in tree.items() for key, value in _leaves(child, f"{path}/{name}").items()}
    if isinstance(tree, list):
        return {key: value for i, child in enumerate(tree) for key, value in _leaves(child, f"{path}[{i}]").items()}
    return {path: float("nan") if tree is None else tree}
