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


def floors() -> dict[str, str]:
    """Each dependency's lowest allowed version in pyproject.toml (runtime and test extra), by name."""
    import tomllib

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
