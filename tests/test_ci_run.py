"""`.ci/run` runs the test command the README's first lines give a newcomer, flag for flag."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


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
