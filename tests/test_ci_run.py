"""`.ci/run` runs the test command the README's first lines give a newcomer, flag for flag."""

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("sianms_cli", "tests", "bench", "scripts", "examples")


def readme_test_command() -> str:
    """The pytest command of the README's second install line (the one that installs and runs the tests)."""
    first_block = ROOT.joinpath("README.md").read_text().split("```")[1]
    install_lines = [line for line in first_block.splitlines() if line.startswith("python3 -m venv")]
    assert len(install_lines) == 2, "the README opens with two commands: the demo and the tests"
    _, pytest_command = install_lines[1].split(" && python -m pytest ")
    return "python -m pytest " + pytest_command


def test_ci_runs_the_readmes_test_command():
    command = readme_test_command()
    assert "-m \"not devkit\"" in command
    assert command in ROOT.joinpath(".ci", "run").read_text().splitlines()


def floors() -> dict[str, str]:
    """Each dependency's lowest allowed version in pyproject.toml (runtime and test extra), by name."""
    tomllib = pytest.importorskip("tomllib")  # Python 3.11 and later

    project = tomllib.loads(ROOT.joinpath("pyproject.toml").read_text())["project"]
    found = {}
    for requirement in [*project["dependencies"], *project["optional-dependencies"]["test"]]:
        name, _, version = requirement.partition(">=")
        found[name.strip().lower()] = version.split(",")[0].strip()
    return found


def release(version: str) -> tuple[int, ...]:
    """``1.25`` and ``1.25.0`` alike."""
    parts = [int(part) for part in version.split(".")]
    return tuple(parts + [0] * (3 - len(parts)))


def test_ci_tests_every_dependency_at_the_floor_pyproject_allows():
    pins = {}
    for line in ROOT.joinpath(".ci", "minimum-versions.txt").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            name, _, version = line.partition("==")
            pins[name.strip().lower()] = version.strip()
    allowed = floors()
    assert set(pins) == set(allowed) - {"torch"}  # torch: the CPU build CI installs (see the file's header)
    assert {name: release(pins[name]) for name in pins} == {name: release(allowed[name]) for name in pins}
    assert "-c .ci/minimum-versions.txt" in ROOT.joinpath(".ci", "run").read_text()


def test_every_source_compiles_on_the_oldest_python_allowed():
    # Only what the oldest Python can parse (3.11's `d['a', *rest]` is a syntax error on 3.10);
    # the suite itself runs on the Python CI has.
    tomllib = pytest.importorskip("tomllib")
    oldest = tomllib.loads(ROOT.joinpath("pyproject.toml").read_text())["project"]["requires-python"].removeprefix(">=")
    interpreter = python_of_version(oldest)
    if interpreter is None:
        pytest.skip(f"no Python {oldest} on PATH or in pyenv")
    probe = ("import pathlib, sys\n"
             "for folder in sys.argv[1:]:\n"
             "    for path in sorted(pathlib.Path(folder).rglob('*.py')):\n"
             "        try:\n"
             "            compile(path.read_text(), str(path), 'exec', dont_inherit=True)\n"
             "        except SyntaxError as error:\n"
             "            print(f'{path}:{error.lineno}: {error.msg}')\n")
    done = subprocess.run([interpreter, "-c", probe, *(str(ROOT / name) for name in SOURCES)], capture_output=True,
                          text=True, check=True)
    assert done.stdout == ""


def python_of_version(version: str) -> str | None:
    """An interpreter of Python ``version`` (``3.10``) that runs: ``python3.10`` on PATH, else one
    that pyenv holds (whose shim on PATH answers only for the versions selected)."""
    candidates = [shutil.which(f"python{version}")]
    if shutil.which("pyenv"):
        listed = subprocess.run(["pyenv", "versions", "--bare"], capture_output=True, text=True).stdout.split()
        root = subprocess.run(["pyenv", "root"], capture_output=True, text=True).stdout.strip()
        candidates += [f"{root}/versions/{name}/bin/python" for name in listed if name.startswith(f"{version}.")]
    for candidate in filter(None, candidates):
        if subprocess.run([candidate, "-c", "pass"], capture_output=True).returncode == 0:
            return candidate
    return None
