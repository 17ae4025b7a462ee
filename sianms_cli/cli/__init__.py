"""The ``sianms`` command line: one module per subcommand, each a thin layer over the library."""

import sys

import typer
from typer.main import get_command

from sianms_cli.cli._app import app
from sianms_cli.processes import terminate_on_sigterm
from sianms_cli.cli import demo, evaluate, info, metrics, prepare, report, synth, train  # noqa: F401  (importing registers the subcommands)


def main() -> None:
    """Console entry point. A flag the parser refuses (a bad type, a value out of range, an
    unknown or missing option) ends, as every other bad input, in one ``error:`` line and
    exit code 2; a bare command still prints its help."""
    terminate_on_sigterm()
    try:
        code = get_command(app).main(prog_name="sianms", standalone_mode=False)
    except typer.TyperException as error:  # typer's click exceptions derive from it
        context = getattr(error, "ctx", None)
        if type(error).__name__ == "NoArgsIsHelpError" or context is None:
            error.show()
        else:
            message = " ".join(error.format_message().split())
            typer.echo(f"error: {context.command_path}: {message} (see '{context.command_path} -h')", err=True)
        sys.exit(error.exit_code)
    except typer.Abort:
        typer.echo("aborted", err=True)
        sys.exit(1)
    sys.exit(code if isinstance(code, int) else 0)
