"""The evaluation pipeline: results against a split, the command's config, the report, the written output."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from metrics_reference import reference_script
from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError
from sianms_cli.metrics import (
    Results,
    ResultsFormatError,
    align_results,
    eval_split,
    evaluate,
    read_report,
    read_results,
)
from sianms_cli.metrics.boxes import empty_boxes, make_boxes
from sianms_cli.metrics.evaluate import MetricsConfig, detail_key, read_details, run
from sianms_cli.io import OutputError

SUMMARY_KEYS = {"label_aps", "mean_dist_aps", "mean_ap", "label_tp_errors", "tp_errors", "tp_scores", "nd_score",
                "eval_time", "cfg", "meta"}


def _results(tokens, boxes=None) -> Results:
    return Results(tuple(tokens), empty_boxes() if boxes is None else boxes)


def test_every_split_sample_must_be_present(reference_db):
    split = eval_split(reference_db, "mini_val")
    with pytest.raises(ResultsFormatError, match="sample of split 'mini_val' missing \\(1 of") as caught:
        align_results(_results(split.sample_tokens[1:]), split)
    assert caught.value.token == split.sample_tokens[0]


def test_predefined_split_refuses_extra_samples_custom_split_ignores_them(reference_db):
    all_tokens = eval_split(reference_db, "custom_all").sample_tokens
    extra = next(t for t in all_tokens if t not in eval_split(reference_db, "mini_val").sample_tokens)
    with pytest.raises(ResultsFormatError, match="not a sample of split 'mini_val'") as caught:
        align_results(_results(all_tokens), eval_split(reference_db, "mini_val"))
    assert caught.value.token == extra
    custom = eval_split(reference_db, "custom_val")
    boxes = make_boxes(np.arange(len(all_tokens)), "car", np.zeros((len(all_tokens), 3)), score=0.5)
    kept, ignored = align_results(_results(all_tokens, boxes), custom)
    assert ignored == len(all_tokens) - len(custom) and len(kept) == len(custom)


def test_custom_split_flattens_in_split_order_predefined_in_file_order(reference_db):
    split = eval_split(reference_db, "custom_val")
    tokens = split.sample_tokens[::-1]  # the file lists the samples backwards
    boxes = make_boxes(np.arange(len(tokens)), "car", np.zeros((len(tokens), 3)), score=np.arange(len(tokens)) / 100)
    kept, _ = align_results(_results(tokens, boxes), split)
    assert kept["sample"].tolist() == list(range(len(tokens)))
    assert kept["score"].tolist() == sorted(boxes["score"].tolist(), reverse=True)
    predefined = eval_split(reference_db, "mini_val")
    kept, _ = align_results(_results(tokens, boxes), predefined)
    assert kept["sample"].tolist() == list(range(len(tokens)))[::-1]


def test_no_prediction_at_all_scores_zero_without_failing(reference_db):
    split = eval_split(reference_db, "mini_val")
    report = evaluate(reference_db, split, _results(split.sample_tokens), "paper", ["all", "overlap"])
    assert list(report.regions) == ["all", "overlap"]
    for region in report.regions.values():
        assert region.mean_ap == 0.0 and region.tp_errors["trans_err"] == 1.0 and region.nd_score == 0.0
        assert sum(region.pred_counts.values()) == 0 and sum(region.gt_counts.values()) > 0
    for summary in report.serialize()["regions"].values():
        assert set(summary) == SUMMARY_KEYS


def _ground_truth_as_predictions(db, split):
    from sianms_cli.metrics.dataset import ground_truth

    gt, _ = ground_truth(db, split)
    gt = gt[gt["num_pts"] != 0]  # GT without points is dropped, a prediction never is
    gt["score"] = np.linspace(1.0, 0.01, len(gt))
    gt["velocity"] = np.nan_to_num(gt["velocity"])
    return _results(split.sample_tokens, gt)


def test_ground_truth_as_predictions_is_perfect(reference_db):
    split = eval_split(reference_db, "custom_all")
    report = evaluate(reference_db, split, _ground_truth_as_predictions(reference_db, split), "paper",
                      ["all", "overlap"])
    for region in report.regions.values():
        for name in ("car", "pedestrian", "bicycle"):
            assert region.mean_dist_aps[name] == pytest.approx(1.0, abs=1e-9)
            assert region.label_tp_errors[name]["trans_err"] == pytest.approx(0.0, abs=1e-12)


def test_a_class_without_gt_in_a_region_scores_as_the_devkit_scores_it(reference_db):
    """The devkit's ``accumulate`` returns ``no_predictions()`` when ``npos == 0``: AP 0, TP errors 1,
    and the class stays in mAP, the mean errors and NDS. Perfect predictions show it plainly."""
    split = eval_split(reference_db, "custom_all")
    report = evaluate(reference_db, split, _ground_truth_as_predictions(reference_db, split), "paper",
                      ["all", "overlap:*"])
    without_gt = {name: region.classes_without_gt for name, region in report.regions.items()}
    assert without_gt == {
        "all": (),
        "overlap:CAM_FRONT|CAM_FRONT_RIGHT": ("pedestrian", "bicycle"),
        "overlap:CAM_FRONT_RIGHT|CAM_BACK_RIGHT": ("pedestrian", "bicycle"),
        "overlap:CAM_BACK_RIGHT|CAM_BACK": ("pedestrian", "bicycle"),
        "overlap:CAM_BACK|CAM_BACK_LEFT": ("car", "pedestrian"),
        "overlap:CAM_BACK_LEFT|CAM_FRONT_LEFT": ("pedestrian",),
        "overlap:CAM_FRONT_LEFT|CAM_FRONT": ("car",),
    }
    for region in report.regions.values():
        for name in region.classes_without_gt:
            assert region.gt_counts[name] == 0
            assert region.label_aps[name] == {"0.5": 0.0, "1.0": 0.0, "2.0": 0.0, "4.0": 0.0}
            assert region.label_tp_errors[name] == dict.fromkeys(region.tp_errors, 1.0)
        assert region.mean_ap == pytest.approx(1 - len(region.classes_without_gt) / 3, abs=1e-12)
        assert region.mean_ap_of_classes_with_gt == pytest.approx(1.0, abs=1e-12)
    # One class of three: mAP 1/3, each mean TP error (0 + 1 + 1) / 3, NDS (5/3 + 5 * 1/3) / 10.
    pair = report.regions["overlap:CAM_FRONT|CAM_FRONT_RIGHT"]
    assert pair.tp_errors == pytest.approx(dict.fromkeys(pair.tp_errors, 2 / 3), abs=1e-12)
    assert pair.nd_score == pytest.approx(1 / 3, abs=1e-12)


def test_run_writes_the_report_and_refuses_to_clobber(reference_folder, tmp_path):
    out = tmp_path / "metrics.json"
    config = _config(reference_folder, regions=("all", "overlap"))
    report = run(config, out)
    written = json.loads(out.read_text())
    assert written["schema"] == "sianms-metrics" and written["schema_version"] == 1
    assert list(written["regions"]) == ["all", "overlap"]
    assert set(written["regions"]["all"]) == SUMMARY_KEYS
    assert written["regions"]["all"]["label_tp_errors"]["traffic_cone"]["orient_err"] is None  # NaN -> null
    assert written["regions"]["all"]["nd_score"] == report.regions["all"].nd_score
    assert written["cfg"]["class_range"]["car"] == 50
    assert read_report(out) == report
    before = out.read_bytes()
    with pytest.raises(OutputExistsError):
        run(config, out)
    assert out.read_bytes() == before
    run(_config(reference_folder, detection_config="paper"), out, overwrite=True)
    assert list(json.loads(out.read_text())["regions"]["all"]["label_aps"]) == ["car", "pedestrian", "bicycle"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["metrics.json"]


def test_details_are_the_curves_evaluate_computed(reference_folder, reference_db, tmp_path):
    config = _config(reference_folder, regions=("all", "overlap"))
    details = tmp_path / "details.json"
    report = run(config, details=details)
    computed = {}
    evaluate(reference_db, config.split, read_results(config.results), config.detection_config, config.regions,
             inspect=lambda region, gt, pred, curves: computed.setdefault(region, curves))
    written = read_details(details)
    assert list(written) == ["all", "overlap"]
    assert written["all"] == {f"{name}:{float(th)}": data for (name, th), data in computed["all"].items()}
    assert written["overlap"] == {detail_key(name, th): data for (name, th), data in computed["overlap"].items()}
    assert len(written["all"]) == len(report.cfg.class_names) * len(report.cfg.dist_ths)
    json.loads(details.read_text(), parse_constant=lambda name: pytest.fail(f"{name} in strict JSON"))
    with pytest.raises(OutputExistsError):
        run(config, details=details)
    with pytest.raises(SianmsError, match="--details: .* is the results file"):
        run(config, details=config.results, overwrite=True)


def test_details_that_are_malformed_name_the_field(tmp_path):
    bad = tmp_path / "details.json"
    bad.write_text(json.dumps({"all": {"car:2.0": {"recall": [0.0] * 101}}}))
    with pytest.raises(DataFormatError, match=r"details.json: field 'all.car:2.0.precision': must be a list of 101"):
        read_details(bad)
    curves = {name: [0.5] * 101 for name in ("recall", "precision", "confidence", "trans_err", "vel_err",
                                             "scale_err", "orient_err", "attr_err")}
    curves["recall"][50] = 10**400  # no float holds it: an OverflowError traceback in `sianms report`
    bad.write_text(json.dumps({"all": {"car:2.0": curves}}))
    with pytest.raises(DataFormatError, match=r"details.json: field 'all.car:2.0.recall': must be a list of 101"):
        read_details(bad)


def test_run_refuses_the_output_before_any_work(reference_folder, tmp_path):
    nowhere = _config(reference_folder, dataroot=str(tmp_path / "no-dataroot"))
    (tmp_path / "taken.json").write_text("{}")
    with pytest.raises(OutputExistsError):
        run(nowhere, tmp_path / "taken.json")
    with pytest.raises(OutputError, match="it is a folder"):
        run(nowhere, tmp_path)
    config = _config(reference_folder)
    for overwrite in (False, True):
        with pytest.raises(SianmsError, match="--out: .* is the results file"):
            run(config, config.results, overwrite=overwrite)


def test_run_never_writes_over_the_dataset_or_its_config_file(reference_folder, tmp_path):
    """`--out D/v1.0-mini/sample.json --overwrite` had replaced a dataset table, `--out c.json` the --config file."""
    config = _config(reference_folder)
    table = Path(config.dataroot) / config.version / "sample.json"
    before = table.read_bytes()
    for flag, place in (("--out", {"out": table}), ("--details", {"details": table})):
        with pytest.raises(SianmsError) as caught:
            run(config, overwrite=True, **place)
        assert str(caught.value) == (f"{flag}: {table} is inside the dataroot {config.dataroot}, which metrics only "
                                     "reads; write it elsewhere")
    assert table.read_bytes() == before
    own = tmp_path / "c.json"
    own.write_text(json.dumps({"min_recall": 0.2}))
    with pytest.raises(SianmsError, match=f"^--out: {own} is the --config file; write it elsewhere$"):
        run(replace(config, detection_config=str(own)), own, overwrite=True)


class _Recorder:
    def __init__(self) -> None:
        self.calls: list[tuple] = []

    def start(self, total, unit, description) -> None:
        self.calls.append(("start", total, unit, description))

    def advance(self, amount=1) -> None:
        self.calls.append(("advance", amount))


def test_run_reports_bytes_read_then_regions_evaluated(reference_folder):
    config = _config(reference_folder, regions=("all", "overlap"))
    recorder = _Recorder()
    run(config, progress=recorder)
    size = Path(config.results).stat().st_size
    starts = [call for call in recorder.calls if call[0] == "start"]
    assert starts == [("start", size, "B", "reading results"), ("start", 2, "region", "evaluating")]
    second = recorder.calls.index(starts[1])
    assert sum(call[1] for call in recorder.calls[1:second]) == size
    assert recorder.calls[second + 1:] == [("advance", 1), ("advance", 1)]


def _config(reference_folder, **changes) -> MetricsConfig:
    case = reference_script.CASES[0]
    fields = {"dataroot": str(reference_folder / "dataroot"), "version": reference_script.VERSION,
              "split": case["split"], "results": str(reference_folder / "results" / f"{case['results']}.json")}
    return MetricsConfig(**{**fields, **changes})


def test_config_normalises_regions_and_paths(reference_folder):
    config = _config(reference_folder, regions=" all, overlap:CAM_BACK|CAM_BACK_LEFT ,,", dataroot=Path("d"))
    assert config.regions == ("all", "overlap:CAM_BACK|CAM_BACK_LEFT") and config.dataroot == "d"


@pytest.mark.parametrize(("changes", "message"), [
    ({"regions": ("all", "x")}, "--region: unknown region 'x'; expected all, overlap, non-overlap"),
    ({"regions": ("overlap:CAM_FRONT|CAM_FRONT",)}, "--region: unknown region 'overlap:CAM_FRONT|CAM_FRONT'"),
    ({"regions": ("overlap:CAM_FRONT",)}, "--region: unknown region"),
    ({"regions": ""}, "--region: no region given"),
    ({"detection_config": "nope"}, "--config: 'nope' is neither a preset (detection_cvpr_2019, paper)"),
    ({"split": " "}, "--split: must not be empty"),
    ({"results": ""}, "--results: must not be empty"),
])
def test_config_names_the_flag_of_a_bad_value(reference_folder, changes, message):
    with pytest.raises(SianmsError) as caught:
        _config(reference_folder, **changes)
    assert str(caught.value).startswith(message)


def test_a_pair_missing_from_the_rigs_is_refused_with_the_valid_pairs(reference_folder):
    with pytest.raises(SianmsError) as caught:
        run(_config(reference_folder, regions=("overlap:CAM_FRONT|CAM_BACK",)))
    assert str(caught.value).startswith("unknown region 'overlap:CAM_FRONT|CAM_BACK'; regions: all, overlap")
    assert "overlap:CAM_FRONT|CAM_FRONT_RIGHT" in str(caught.value)


def test_the_configs_box_limit_applies_to_results_read_with_another(reference_folder, reference_db, tmp_path):
    from sianms_cli.metrics import DetectionConfig

    results = read_results(reference_folder / "results" / "perturbed_mini_val.json")
    assert results.validated
    strict = DetectionConfig.from_dict({"max_boxes_per_sample": 2}, name="strict")
    with pytest.raises(ResultsFormatError, match="at most 2 per sample"):
        evaluate(reference_db, "mini_val", results, strict)
