"""`sianms zoo`: the pretrained networks shipped with sianms, with their held-out figures."""

from __future__ import annotations

import json

import typer

from sianms_cli.cli._app import command


def _figure(value: object) -> str:
    return f"{value:.3f}" if isinstance(value, float) else str(value)


@command("zoo")
def zoo_cli(
    as_json: bool = typer.Option(False, "--json", help="Print every model card as JSON (and nothing else)."),
) -> None:
    """List the model zoo: networks trained by sianms's own commands, usable as `--fpointnet zoo:NAME`,
    `--siamese zoo:NAME` and `train ... --init zoo:NAME` (docs/model_zoo.md)."""
    from sianms_cli import zoo

    cards = [zoo.card(name) for name in zoo.names()]
    if as_json:
        typer.echo(json.dumps(cards, indent=2))
        return
    if not cards:
        typer.echo("no zoo entry is shipped with this installation")
        return
    for record in cards:
        typer.echo(f"{zoo.PREFIX}{record['name']}  ({record['model']}, {record['bytes'] / 2**20:.1f} MiB)\n"
                   f"  {record['summary']}")
        held_out = record["held_out"]
        typer.echo(f"  held out: {held_out.get('description', '')}")
        for name, figures in held_out.get("figures", {}).items():
            typer.echo(f"    {name}: " + ", ".join(f"{key} {_figure(value)}" for key, value in figures.items()))
