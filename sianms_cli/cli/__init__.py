"""The ``sianms`` command line: one module per subcommand, each a thin layer over the library."""

import sys

import typer
from typer.main import get_command

from sianms_cli.cli._app import app, exit_code_after_signals, say_error
from sianms_cli.processes import exit_on_signals, interrupt_on_signals, signal_received
from sianms_cli.cli import demo, evaluate, info, metrics, prepare, report, synth, train, zoo  # noqa: F401  (importing registers the subcommands)


def main() -> None:
    """Console entry point. A flag the parser refuses (a bad type, a value out of range, an
    unknown or missing option) ends, as every other bad input, in one ``error:`` line and
    exit code 2; a bare group (``sianms``, ``sianms train``) prints its help, then that line.
    SIGINT, SIGTERM and SIGHUP end in 130, 143 and 129 with one ``interrupted`` line, wherever they land
    (:func:`exit_code_after_signals`); once the command has ended, they end the process at once
    with the code it chose (:func:`~sianms_cli.processes.exit_on_signals`)."""
    interrupt_on_signals()
    try:
        code = get_command(app).main(prog_name="sianms", standalone_mode=False)
    except typer.TyperException as error:  # typer's click exceptions derive from it
        context = getattr(error, "ctx", None)
        bare_group = type(error).__name__ == "NoArgsIsHelpError"
        if bare_group or context is None:
            # typer declares show() on ClickException, a private class; every TyperException it raises is one
            error.show()  # type: ignore[attr-defined]
        if context is not None:
            message = "missing command." if bare_group else " ".join(error.format_message().split())
            say_error(f"error: {context.command_path}: {message} (see '{context.command_path} -h')")
        code = error.exit_code
    except typer.Abort:  # click's word for a KeyboardInterrupt while it parsed
        if signal_received() is None:
            typer.echo("aborted", err=True)
        code = 1
    except KeyboardInterrupt:  # one that came before a command's own handling, or after it
        code = 130
    code = exit_code_after_signals(code if isinstance(code, int) else 0)
    exit_on_signals(code)
    sys.exit(code)
