"""The sources stay `ruff check` clean under the rules pyproject.toml sets ([tool.ruff]), and the
package passes `mypy` under its configuration there ([tool.mypy])."""

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


def test_mypy_finds_nothing_in_the_package(tmp_path):
    if importlib.util.find_spec("mypy") is None:
        pytest.skip("mypy is not installed (it comes with the test extra: pip install -e '.[test]')")
    # The files to check come from [tool.mypy]; the cache goes to a temporary folder, so a test
    # writes nothing into the source tree.
    command = [sys.executable, "-m", "mypy", "--cache-dir", str(tmp_path / "mypy_cache")]
    finished = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=600)
    if finished.returncode != 0:
        pytest.fail(f"`mypy` exited {finished.returncode}:\n{finished.stdout}{finished.stderr}", pytrace=False)
