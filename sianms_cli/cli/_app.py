"""The Typer application every subcommand module registers on."""

from __future__ import annotations

import functools
from typing import Callable

import typer

from sianms_cli import __version__
from sianms_cli.errors import SianmsError

app = typer.Typer(
    name="sianms",
    help="Multi-camera 3D object detection research on nuScenes-format data.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"sianms {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_print_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """Multi-camera 3D object detection research on nuScenes-format data."""


def command(name: str) -> Callable[[Callable], Callable]:
    """Register a subcommand whose user errors print one line and exit with code 2."""

    def register(function: Callable) -> Callable:
        @functools.wraps(function)
        def run(*args, **kwargs):
            try:
                return function(*args, **kwargs)
            except SianmsError as error:
                typer.echo(f"error: {error}", err=True)
                raise typer.Exit(error.exit_code) from None

        return app.command(name)(run)

    return register
