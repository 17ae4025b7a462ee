"""scripts/zoo_study_world.sh: one world of the zoo study, and a further arm on it (--arm), each stage run here
with stand-ins for sianms and the calibration carver that record their arguments and leave what the next stage
reads."""

import json
import os
import shutil
import stat
import subprocess
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "zoo_study_world.sh"
SEED = "103"

SIANMS = """#!/usr/bin/env bash
echo "sianms $*" >> "$CALLS"
command=$1 out=
detector=$(printf '%s\\n' "$@" | grep '^zoo:')
while [ $# -gt 0 ]; do [ "$1" = --out ] && out=$2; shift; done
mkdir -p "$out"
case "$command" in
  synth) echo '{}' > "$out/sianms-synth.json" ;;
  eval) echo '{"complete": true}' > "$out/eval.json"
        echo "${BOXES_OVERRIDE:-$detector}" > "$out/results_vanilla.json" ;;  # the boxes: the detector's
esac
"""


@pytest.fixture
def repository(tmp_path):
    """A copy of the script in a stand-in repository, the stand-in sianms on PATH, and where calls go."""
    scripts = tmp_path / "repo" / "scripts"
    scripts.mkdir(parents=True)
    shutil.copy(SCRIPT, scripts / SCRIPT.name)
    (scripts / "carve_calibration.py").write_text(
        "import os, sys\nopen(os.environ['CALLS'], 'a').write('carve ' + ' '.join(sys.argv[1:]) + '\\n')\n")
    sianms = tmp_path / "bin" / "sianms"
    sianms.parent.mkdir()
    sianms.write_text(SIANMS)
    sianms.chmod(sianms.stat().st_mode | stat.S_IXUSR)
    return tmp_path


def run_world(root: Path, *options: str, **environment):
    calls = root / "calls.txt"
    calls.unlink(missing_ok=True)
    env = {**os.environ, "PATH": f"{root / 'bin'}{os.pathsep}{os.environ['PATH']}", "CALLS": str(calls),
           **environment}
    finished = subprocess.run(["bash", str(root / "repo" / "scripts" / SCRIPT.name), SEED, str(root / "study"),
                               *options], env=env, capture_output=True, text=True)
    return finished, [line.split()[:2] + [w for w in line.split() if w.startswith("zoo:")]
                      for line in calls.read_text().splitlines()] if calls.exists() else []


def costs(root: Path, name: str) -> list[str]:
    return [json.loads(line)["stage"] for line in (root / "study" / f"s{SEED}" / name).read_text().splitlines()]


def test_the_first_arm_runs_every_stage_once_and_a_rerun_only_says_done(repository):
    finished, calls = run_world(repository, "--prune")
    assert finished.returncode == 0, finished.stderr
    assert calls == [["sianms", "synth"], ["carve", "--dataroot"], *[["sianms", "prepare"]] * 3,
                     ["sianms", "train"], ["sianms", "eval", "zoo:fpointnet-single"],
                     ["sianms", "eval", "zoo:fpointnet-single"]]
    assert costs(repository, "costs.jsonl") == ["synth", "prepare-train_fit", "prepare-calib", "prepare-val",
                                                "siamese", "eval-calib", "eval-val"]
    world = repository / "study" / f"s{SEED}"
    assert sorted(p.name for p in world.iterdir()) == ["costs.jsonl", "eval-calib", "eval-val", "siamese"]
    finished, calls = run_world(repository, "--prune")
    assert (finished.returncode, finished.stdout, calls) == (0, f"s{SEED}: done\n", [])


def test_a_further_arm_remakes_the_world_checks_the_first_arms_boxes_then_evaluates_its_detector(repository):
    run_world(repository, "--prune")
    finished, calls = run_world(repository, "--prune", "--arm", "fpointnet-multiview")
    assert finished.returncode == 0, finished.stderr
    assert calls == [["sianms", "synth"], ["carve", "--dataroot"], ["sianms", "prepare"], ["sianms", "prepare"],
                     ["sianms", "eval", "zoo:fpointnet-single"], ["sianms", "eval", "zoo:fpointnet-multiview"],
                     ["sianms", "eval", "zoo:fpointnet-multiview"]]
    assert costs(repository, "costs-fpointnet-multiview.jsonl") == [
        "synth", "prepare-calib", "prepare-val", "eval-val-again", "eval-calib-fpointnet-multiview",
        "eval-val-fpointnet-multiview"]
    assert finished.stdout.endswith(f"s{SEED} (fpointnet-multiview): done\n")


def test_a_further_arm_stops_where_the_first_arms_boxes_come_out_otherwise(repository):
    run_world(repository)
    finished, calls = run_world(repository, "--arm", "fpointnet-multiview", BOXES_OVERRIDE="other boxes")
    assert finished.returncode == 1
    assert finished.stderr.startswith(f"error: {repository / 'study' / f's{SEED}' / 'eval-val-again'}: "
                                      "results_vanilla.json differs from the first arm's")
    assert calls == [["carve", "--dataroot"], ["sianms", "prepare"], ["sianms", "prepare"],
                     ["sianms", "eval", "zoo:fpointnet-single"]]  # the world was kept: no synth


def test_a_further_arm_needs_the_first_and_an_unknown_option_is_refused(repository):
    finished, calls = run_world(repository, "--arm", "fpointnet-multiview")
    assert (finished.returncode, calls) == (2, [])
    assert finished.stderr == (f"error: {repository / 'study' / f's{SEED}' / 'eval-val'}: the first arm of world "
                               f"{SEED} is not done; run it before --arm\n")
    finished, _ = run_world(repository, "--purne")
    assert (finished.returncode, finished.stderr) == (2, "error: --purne: unknown option (--prune, --arm ENTRY)\n")
