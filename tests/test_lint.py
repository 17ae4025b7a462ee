"""The sources stay `ruff check` clean under the rules pyproject.toml sets ([tool.ruff])."""

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("sianms_cli", "tests", "bench", "scripts", "examples")


def test_ruff_finds_nothing_in_the_sources():
    if importlib.util.find_spec("ruff") is None:
        pytest.skip("ruff is not installed (it comes with the test extra: pip install -e '.[test]')")
    # --no-cache: a test writes nothing into the source tree.
    command = [sys.executable, "-m", "ruff", "check", "--no-cache", "--output-format", "concise", *SOURCES]
    finished = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=120)
    if finished.returncode != 0:
        pytest.fail(f"`ruff check {' '.join(SOURCES)}` exited {finished.returncode}:\n"
                    f"{finished.stdout}{finished.stderr}", pytrace=False)
