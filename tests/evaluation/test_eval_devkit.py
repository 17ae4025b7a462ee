"""Opt-in: `sianms eval`'s results files load in the official nuscenes-devkit and score the same there.

Runs the devkit's ``DetectionEval`` (its own interpreter, ``scripts/devkit_dump.py --results``)
on each results file of an evaluation of the generated mini, and compares its AP and TP
errors with `sianms metrics`' evaluator on the same file. Skipped without the devkit venv.
"""

import json
import subprocess

import numpy as np
import pytest
from devkit_venv import DEVKIT_MARKS, DEVKIT_PYTHON, REPO_ROOT

from sianms_cli.metrics.evaluate import evaluate
from sianms_cli.metrics.results import read_results
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.evaluation.job import EvalConfig, run

DUMP_SCRIPT = REPO_ROOT / "scripts" / "devkit_dump.py"
pytestmark = DEVKIT_MARKS


def test_results_files_pass_the_devkit_with_the_same_metrics(eval_inputs, tmp_path):
    out = tmp_path / "eval"
    run(EvalConfig(dataroot=str(eval_inputs.dataroot), version="v1.0-mini", split=eval_inputs.split,
                   cache=str(eval_inputs.cache), siamese=str(eval_inputs.siamese),
                   fpointnet=str(eval_inputs.fpointnet), methods="vanilla,sianms,hybrid", pictures=0), out)
    db = NuScenesDB(eval_inputs.dataroot, "v1.0-mini")
    for method in ("vanilla", "sianms", "hybrid"):
        path = out / f"results_{method}.json"
        dump = tmp_path / f"devkit_{method}.json"
        done = subprocess.run([str(DEVKIT_PYTHON), str(DUMP_SCRIPT), str(eval_inputs.dataroot), "v1.0-mini", str(dump),
                               "--split", eval_inputs.split, "--results", str(path), "--max-samples", "1"],
                              capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr
        devkit = json.loads(dump.read_text())["evaluation"]
        ours = evaluate(db, eval_inputs.split, read_results(path), "detection_cvpr_2019").regions["all"]
        for name, ap in devkit["mean_dist_aps"].items():
            assert ours.mean_dist_aps[name] == pytest.approx(ap, abs=1e-12), (method, name)
            for metric, value in devkit["label_tp_errors"][name].items():
                mine = ours.label_tp_errors[name][metric]
                assert (value is None and np.isnan(mine)) or mine == pytest.approx(value, abs=1e-12), (method, metric)
