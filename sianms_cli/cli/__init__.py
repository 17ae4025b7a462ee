"""The ``sianms`` command line: one module per subcommand, each a thin layer over the library."""

from sianms_cli.cli._app import app
from sianms_cli.processes import terminate_on_sigterm
from sianms_cli.cli import demo, evaluate, info, metrics, prepare, report, synth, train  # noqa: F401  (importing registers the subcommands)


def main() -> None:
    """Console entry point."""
    terminate_on_sigterm()
    app(prog_name="sianms")
