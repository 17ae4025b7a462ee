"""examples/slurm_zoo_study.sh: one array task per world of the zoo study, then the report once
every world is done; each stage run here with stand-ins for sbatch, the world script and sianms."""

import os
import stat
import subprocess
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "examples" / "slurm_zoo_study.sh"
SEEDS = ["101", "102", "103", "104", "105", "106", "107"]


def stand_in(path: Path, body: str) -> None:
    """An executable that appends its arguments to calls.txt, then runs ``body``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f'#!/usr/bin/env bash\necho "$(basename "$0") $*" >> "$CALLS"\n{body}\n')
    path.chmod(path.stat().st_mode | stat.S_IXUSR)


def run_stage(tmp_path, *arguments, **environment):
    calls = tmp_path / "calls.txt"
    env = {**os.environ, "PATH": f"{tmp_path / 'bin'}{os.pathsep}{os.environ['PATH']}", "CALLS": str(calls),
           "WORK": str(tmp_path / "work"), "ZOO_STUDY_ROOT": str(tmp_path / "repo"), **environment}
    finished = subprocess.run(["bash", str(SCRIPT), *arguments], env=env, capture_output=True, text=True)
    return finished, calls.read_text().splitlines() if calls.exists() else []


def test_submit_queues_one_task_per_world_then_the_report_after_them(tmp_path):
    stand_in(tmp_path / "bin" / "sbatch", 'echo $((4000 + $(wc -l < "$CALLS")))')
    finished, calls = run_stage(tmp_path)
    assert finished.returncode == 0, finished.stderr
    worlds, report = calls
    assert "--array=0-6" in worlds.split() and worlds.endswith(" world")
    assert "--dependency=afterok:4001" in report.split() and report.endswith(" report")
    assert "worlds 4001, report 4002" in finished.stdout


def test_a_world_task_runs_its_seeds_world_with_pruning(tmp_path):
    stand_in(tmp_path / "repo" / "scripts" / "zoo_study_world.sh", "")
    for task, seed in enumerate(SEEDS):
        finished, calls = run_stage(tmp_path, "world", SLURM_ARRAY_TASK_ID=str(task))
        assert finished.returncode == 0, finished.stderr
        assert calls[-1] == f"zoo_study_world.sh {seed} {tmp_path / 'work'} --prune"


def test_the_report_reads_every_worlds_validation_and_writes_the_page(tmp_path):
    stand_in(tmp_path / "bin" / "sianms", "")
    finished, calls = run_stage(tmp_path, "report")
    assert finished.returncode == 0, finished.stderr
    work = tmp_path / "work"
    runs = " ".join(str(work / f"s{seed}" / "eval-val") for seed in SEEDS)
    page = tmp_path / "repo" / "docs" / "results" / "zoo_study.md"
    assert calls == [f"sianms report {runs} --out {work / 'report'} --page {page}"]


def test_an_unknown_stage_is_one_error_line(tmp_path):
    finished, _ = run_stage(tmp_path, "wolrd")
    assert (finished.returncode, finished.stderr) == (2, "error: wolrd: unknown stage (submit, world or report)\n")
