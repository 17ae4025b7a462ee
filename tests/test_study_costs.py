"""scripts/study_costs.py: per-world and whole-study wall time and disk from costs.jsonl files."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "study_costs.py"
spec = importlib.util.spec_from_file_location("study_costs", SCRIPT)
study_costs = sys.modules["study_costs"] = importlib.util.module_from_spec(spec)
spec.loader.exec_module(study_costs)


def costs_file(path, seed, stages):
    path.write_text("".join(json.dumps({"seed": seed, "stage": stage, "seconds": seconds, "bytes": size,
                                        "finished": "2026-12-06T08:00:00Z"}) + "\n"
                            for stage, seconds, size in stages))
    return path


def test_parts_of_a_resumed_stage_add_up_and_the_study_peak_counts_what_earlier_worlds_kept(tmp_path):
    first = costs_file(tmp_path / "a.jsonl", 1, [
        ("synth", 500, 30e9), ("prepare-train_fit", 60, 4e8), ("prepare-val", 20, 1e8),
        ("siamese", 80, 5e6), ("eval-calib", 40, 9e7), ("eval-val", 30, 8e7), ("eval-val", 10, 8.5e7)])
    second = costs_file(tmp_path / "b.jsonl", 2, [("synth", 600, 31e9), ("siamese", 70, 5e6)])
    worlds = study_costs.world_costs(study_costs.read_costs(first) + study_costs.read_costs(second))
    assert worlds[1] == {"synth": 500, "prepare": 80, "siamese": 80, "eval": 80, "total": 740,
                         "peak": 30e9 + 4e8 + 1e8 + 5e6 + 9e7 + 8.5e7, "kept": 5e6 + 9e7 + 8.5e7}
    table = study_costs.markdown(worlds).splitlines()
    assert table[2] == "| 1 | 500 | 80 | 80 | 80 | 12.3 | 30.7 | 180 |"
    assert table[3] == "| 2 | 600 | 0 | 70 | 0 | 11.2 | 31.0 | 5 |"
    assert table[4] == "| all 2 | 1,100 | 80 | 150 | 80 | 23.5 | 31.2 | 185 |"  # 31.005 GB after 0.18 kept


def test_a_line_that_is_not_a_cost_is_one_error_line_naming_file_and_line(tmp_path):
    path = costs_file(tmp_path / "c.jsonl", 1, [("synth", 5, 10)])
    path.write_text(path.read_text() + '{"seed": 1, "stage": "prepare-val", "seconds": -3, "bytes": 1}\n')
    result = subprocess.run([sys.executable, str(SCRIPT), str(path)], capture_output=True, text=True)
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr.startswith(f"error: {path}: line 2: not a costs line") and result.stderr.count("\n") == 1
