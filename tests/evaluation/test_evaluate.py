"""The evaluation pipeline: results against a split, the report, the written output."""

from __future__ import annotations

import json

import numpy as np
import pytest

from metrics_reference import reference_script
from sianms_cli.errors import OutputExistsError
from sianms_cli.evaluation import (
    Results,
    ResultsFormatError,
    align_results,
    eval_split,
    evaluate,
    format_report,
    read_results,
    run_metrics,
)
from sianms_cli.evaluation.boxes import empty_boxes, make_boxes

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
    for summary in report["regions"].values():
        assert set(summary) == SUMMARY_KEYS
        assert summary["mean_ap"] == 0.0 and summary["tp_errors"]["trans_err"] == 1.0
        assert summary["nd_score"] == 0.0


def test_ground_truth_as_predictions_is_perfect(reference_db):
    from sianms_cli.evaluation.dataset import ground_truth

    split = eval_split(reference_db, "custom_all")
    gt, _ = ground_truth(reference_db, split)
    gt = gt[gt["num_pts"] != 0]  # GT without points is dropped, a prediction never is
    gt["score"] = np.linspace(1.0, 0.01, len(gt))
    gt["velocity"] = np.nan_to_num(gt["velocity"])
    report = evaluate(reference_db, split, _results(split.sample_tokens, gt), "paper", ["all", "overlap"])
    for summary in report["regions"].values():
        for name in ("car", "pedestrian", "bicycle"):
            assert summary["mean_dist_aps"][name] == pytest.approx(1.0, abs=1e-9)
            assert summary["label_tp_errors"][name]["trans_err"] == pytest.approx(0.0, abs=1e-12)


def test_run_metrics_writes_the_report_and_refuses_to_clobber(reference_folder, tmp_path):
    case = reference_script.CASES[0]
    out = tmp_path / "metrics.json"
    arguments = (reference_folder / "dataroot", reference_script.VERSION, case["split"],
                 reference_folder / "results" / f"{case['results']}.json")
    report = run_metrics(*arguments, regions=["all", "overlap"], out=out)
    written = json.loads(out.read_text())
    assert set(written["regions"]) == {"all", "overlap"}
    assert set(written["regions"]["all"]) == SUMMARY_KEYS
    assert written["regions"]["all"]["label_tp_errors"]["traffic_cone"]["orient_err"] is None  # NaN -> null
    assert written["regions"]["all"]["nd_score"] == report["regions"]["all"]["nd_score"]
    assert written["cfg"]["class_range"]["car"] == 50
    before = out.read_bytes()
    with pytest.raises(OutputExistsError):
        run_metrics(*arguments, out=out)
    assert out.read_bytes() == before
    run_metrics(*arguments, config="paper", out=out, overwrite=True)
    assert list(json.loads(out.read_text())["regions"]["all"]["label_aps"]) == ["car", "pedestrian", "bicycle"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["metrics.json"]


def test_table_lists_every_class_threshold_and_error(reference_folder, reference_db):
    case = reference_script.CASES[0]
    results = read_results(reference_folder / "results" / f"{case['results']}.json")
    text = format_report(evaluate(reference_db, case["split"], results, "detection_cvpr_2019", ["all", "overlap"]))
    for word in ("region all", "region overlap", "AP@0.5", "AP@4.0", "ATE", "ASE", "AOE", "AVE", "AAE",
                 "traffic_cone", "mAP", "NDS"):
        assert word in text


def test_the_configs_box_limit_applies_to_results_read_with_another(reference_folder, reference_db, tmp_path):
    from sianms_cli.evaluation import DetectionConfig

    results = read_results(reference_folder / "results" / "perturbed_mini_val.json")
    assert results.validated
    strict = DetectionConfig.from_dict({"max_boxes_per_sample": 2}, name="strict")
    with pytest.raises(ResultsFormatError, match="at most 2 per sample"):
        evaluate(reference_db, "mini_val", results, strict)
