"""scripts/seed_table.py: Table I over seeds from report.json files."""

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "seed_table.py"
METHODS = ["vanilla", "axis-nms", "axis-nms@0.1", "rotated-nms", "circle-nms", "sianms", "hybrid", "oracle"]


def report(offset: float, gt: int, best: str) -> dict:
    """A report whose car AP is 10 * (method index) + offset in All and that minus 5 in Overlap;
    ATE is 0.1 * index."""
    regions = {region: {m: {"car": {"AP": 10.0 * i + offset - shift, "ATE": 0.1 * i, "ASE": 20.0, "AOE": 0.5,
                                    "gt": gt}}
                        for i, m in enumerate(METHODS)}
               for region, shift in (("all", 0.0), ("overlap", 5.0))}
    return {"methods": METHODS, "regions": regions, "best_nms": {"axis-nms": best, "rotated-nms": "rotated-nms"},
            "reidentification": {"sianms": {"precision": 0.8, "recall": 0.9, "pairs_true": gt // 10}}}


def run(tmp_path, reports):
    paths = []
    for k, r in enumerate(reports):
        paths.append(tmp_path / f"r{k}.json")
        paths[-1].write_text(json.dumps(r))
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, paths)], capture_output=True, text=True)


def test_mean_spread_best_threshold_and_paired_differences(tmp_path):
    result = run(tmp_path, [report(0.0, 100, "axis-nms@0.1"), report(2.0, 120, "axis-nms")])
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    # vanilla AP 0 and 2: mean 1.0, sample sd 1.414
    assert "| All | vanilla | 1.0 ± 1.4 | 0.000 ± 0.000 | 20.0 ± 0.0 | 0.500 ± 0.000 | 45.5 / 0.331 / 18.4 / 0.371 | 100, 120 |" in lines
    # best threshold per run: axis-nms@0.1 (AP 20) in run 0, axis-nms (AP 12) in run 1
    assert any(line.startswith("| All | axis-nms (best) | 16.0 ± 5.7 |") for line in lines)
    # sianms (index 5) minus vanilla: 50 points in both runs; ATE 0.5 m
    assert "| sianms − vanilla | +50.0 ± 0.0 (+50.0, +50.0) | +0.500 ± 0.000 (+0.500, +0.500) |" in lines
    assert lines[-1] == "siaNMS matches: precision 0.80 ± 0.00, recall 0.90 ± 0.00 (true pairs per run: 10, 12)"


def test_one_run_or_different_methods_are_refused(tmp_path):
    assert run(tmp_path, [report(0.0, 100, "axis-nms")]).returncode == 2
    other = report(0.0, 100, "axis-nms")
    other["methods"] = METHODS[:-1]
    refused = run(tmp_path, [report(0.0, 100, "axis-nms"), other])
    assert refused.returncode == 2 and "different methods" in refused.stderr



def test_a_newer_method_appears_only_when_every_run_evaluated_it(tmp_path):
    runs = [report(0.0, 100, "axis-nms"), report(2.0, 120, "axis-nms")]
    for r in runs:  # gated-sianms beside the oracle: index 8 in All, AP 80 + offset
        r["methods"] = METHODS + ["gated-sianms"]
        for region, shift in (("all", 0.0), ("overlap", 5.0)):
            r["regions"][region]["gated-sianms"] = {"car": {"AP": 80.0 + (r["regions"]["all"]["vanilla"]["car"]["AP"])
                                                            - shift, "ATE": 0.8, "ASE": 20.0, "AOE": 0.5, "gt": 100}}
        r["reidentification"]["gated-sianms"] = {"precision": 0.95, "recall": 0.7, "pairs_true": 10}
    lines = run(tmp_path, runs).stdout.splitlines()
    assert "| gated-sianms − vanilla | +80.0 ± 0.0 (+80.0, +80.0) | +0.800 ± 0.000 (+0.800, +0.800) |" in lines
    assert lines[-1] == "Gated siaNMS matches: precision 0.95 ± 0.00, recall 0.70 ± 0.00 (true pairs per run: 10, 10)"
    older = run(tmp_path, [report(0.0, 100, "axis-nms"), report(2.0, 120, "axis-nms")]).stdout
    assert "gated-sianms" not in older and "Gated" not in older
