"""Start-up stays fast: `--help` imports no numpy, and commands that need no torch never load it."""

import json
import subprocess
import sys

import pytest

PROBE = """
import json, sys
from sianms_cli.cli import main
sys.argv = ["sianms", *json.loads(sys.argv[1])]
try:
    main()
except SystemExit:
    pass
sys.stdout = sys.__stdout__
print(json.dumps(sorted(name for name in ("torch", "numpy", "pyarrow") if name in sys.modules)))
"""


def modules_loaded_by(arguments):
    """The heavy modules a fresh interpreter has imported once ``sianms ARGUMENTS`` returns."""
    done = subprocess.run([sys.executable, "-c", PROBE, json.dumps(arguments)], capture_output=True, text=True,
                          check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("arguments", [["--help"], ["-h"], ["prepare", "--help"], ["synth", "-h"], ["metrics", "-h"],
                                       ["info", "-h"], ["train", "-h"], ["train", "siamese", "-h"], ["eval", "-h"],
                                       ["report", "-h"], ["demo", "-h"], ["--version"]])
def test_help_imports_nothing_heavy(arguments):
    assert modules_loaded_by(arguments) == []


def test_info_and_metrics_do_not_import_torch(synthetic_dataroot, tmp_path):
    dataroot = str(synthetic_dataroot())
    assert "torch" not in modules_loaded_by(["info", "--dataroot", dataroot, "--quiet", "--max-sweeps", "1"])
    results = tmp_path / "results.json"
    results.write_text(json.dumps({"meta": {}, "results": {}}))
    assert "torch" not in modules_loaded_by(["metrics", "--dataroot", dataroot, "--split", "mini_val",
                                             "--results", str(results), "--quiet"])


def test_the_report_never_imports_torch(eval_folders, tmp_path):
    evaluation = eval_folders.make_eval(tmp_path / "eval", details=True)
    assert "torch" not in modules_loaded_by(["report", str(evaluation), "--quiet"])
    assert (evaluation / "report" / "pr_curves.png").is_file()
