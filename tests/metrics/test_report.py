"""The metrics report: written, read back equal; a damaged file is named with its field."""

from __future__ import annotations

import json
import math

import pytest

from metrics_reference import reference_script
from sianms_cli.errors import DataFormatError
from sianms_cli.metrics import evaluate, read_results
from sianms_cli.metrics.report import MetricsReport, read_report, report_json, write_report


@pytest.fixture(scope="module")
def report(reference_folder, reference_db) -> MetricsReport:
    case = reference_script.CASES[0]
    results = read_results(reference_folder / "results" / f"{case['results']}.json")
    return evaluate(reference_db, case["split"], results, "detection_cvpr_2019", ["all", "overlap", "overlap:*"])


def test_a_written_report_reads_back_equal_and_rewrites_to_the_same_bytes(report, tmp_path):
    path = write_report(tmp_path / "metrics.json", report)
    again = read_report(path)
    assert again == report
    assert list(again.regions) == list(report.regions) and again.cfg == report.cfg
    assert math.isnan(again.regions["all"].label_tp_errors["traffic_cone"]["orient_err"])
    assert again.regions["overlap"].classes_without_gt == report.regions["overlap"].classes_without_gt
    write_report(tmp_path / "again.json", again)
    assert (tmp_path / "again.json").read_bytes() == path.read_bytes()


def test_reports_that_differ_in_one_number_are_not_equal(report):
    content = report.serialize()
    content["regions"]["overlap"]["label_aps"]["car"]["2.0"] += 1e-12
    assert MetricsReport.deserialize(content) != report


def test_each_region_is_a_devkit_metrics_summary(report):
    content = json.loads(report_json(report))
    assert content["schema"] == "sianms-metrics" and content["schema_version"] == 1
    for name, region in content["regions"].items():
        assert list(region) == ["label_aps", "mean_dist_aps", "mean_ap", "label_tp_errors", "tp_errors",
                                "tp_scores", "nd_score", "eval_time", "cfg", "meta"]
        assert region["cfg"] == content["cfg"] and region["meta"] == content["meta"]
        assert list(content["region_boxes"][name]) == ["gt", "pred"]
    assert list(content["boxes"]["pred"]) == ["loaded", "kept", "out_of_range", "without_points", "in_bicycle_rack",
                                              "ignored_samples"]


def _set(path: str, value):
    def change(content: dict) -> None:
        *parents, last = path.split("/")
        for key in parents:
            content = content[key]
        content[last] = value
    return change


def _delete(path: str):
    def change(content: dict) -> None:
        *parents, last = path.split("/")
        for key in parents:
            content = content[key]
        del content[last]
    return change


@pytest.mark.parametrize(("change", "message"), [
    (_set("schema", "nuscenes"), "field 'schema': not a sianms metrics report: expected 'sianms-metrics'"),
    (_set("schema_version", 2), "field 'schema_version': this sianms reads version 1, got 2"),
    (_delete("seconds"), "field 'seconds': missing"),
    (_set("extra", 1), "field 'extra': unexpected; expected only schema, schema_version"),
    (_delete("regions/all/mean_ap"), "field 'regions.all.mean_ap': missing"),
    (_set("regions/all/label_aps/car/0.5", "1"), "field 'regions.all.label_aps.car.0.5': must be a number, got '1'"),
    (_delete("regions/overlap/label_aps/truck"), "field 'regions.overlap.label_aps.truck': missing"),
    (_set("regions/all/nd_score", None), "field 'regions.all.nd_score': must be a number, got None"),
    (_set("regions/all/tp_errors/vel_err", True), "field 'regions.all.tp_errors.vel_err': must be a number or null"),
    (_set("regions/all/cfg/dist_th_tp", 3.0), "field 'regions.all.cfg': differs from the report's cfg"),
    (_set("cfg/dist_th_tp", 3.0), "field 'cfg.dist_th_tp': must be one of dist_ths"),
    (_delete("region_boxes/overlap"), "field 'region_boxes.overlap': missing"),
    (_set("region_boxes/all/gt/car", 1.5), "field 'region_boxes.all.gt.car': must be a non-negative integer"),
    (_set("boxes/gt/kept", -1), "field 'boxes.gt.kept': must be a non-negative integer, got -1"),
    (_set("regions/all", []), "field 'regions.all': must be an object, got list"),
])
def test_a_damaged_report_is_named_with_its_field(report, tmp_path, change, message):
    content = report.serialize()
    change(content)
    path = tmp_path / "metrics.json"
    path.write_text(json.dumps(content))
    with pytest.raises(DataFormatError) as caught:
        read_report(path)
    assert str(caught.value).startswith(f"{path}: {message}")


def test_a_file_that_is_not_json_is_named_with_its_line(tmp_path):
    path = tmp_path / "metrics.json"
    path.write_text('{"schema":\n}')
    with pytest.raises(DataFormatError, match="invalid JSON at line 2"):
        read_report(path)
