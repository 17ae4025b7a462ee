"""Make a model-zoo entry (sianms_cli/zoo/<name>.pt and <name>.json) from a finished training run.

The model card records the exact commands that made the run (``--command``, once per command, in
order), the commit, the machine, the training's per-epoch figures and the held-out figures
(``--held-out``: JSON files whose ``figures`` objects are merged; e.g. the output of
scripts/zoo_held_out.py, or a class -> metrics object from `sianms metrics --out`). See
docs/model_zoo.md for how the shipped entries were made.

Run it from the folder the training ran in: the run's config names its cache relative to it.

Usage: python scripts/make_zoo_entry.py RUN NAME --summary TEXT --commit SHA --machine TEXT
                                        --command "sianms ..." [--command ...]
                                        --held-out-description TEXT [--held-out FILE.json ...]
"""

from __future__ import annotations

import argparse
import json

from sianms_cli.errors import SianmsError
from sianms_cli.zoo.export import export_entry


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run")
    parser.add_argument("name")
    parser.add_argument("--summary", required=True)
    parser.add_argument("--commit", required=True)
    parser.add_argument("--machine", required=True)
    parser.add_argument("--command", action="append", required=True, dest="commands")
    parser.add_argument("--held-out-description", required=True)
    parser.add_argument("--held-out", action="append", default=[])
    args = parser.parse_args()
    figures: dict = {}
    for path in args.held_out:
        with open(path, encoding="utf-8") as file:
            figures.update(json.load(file)["figures"])
    try:
        card = export_entry(args.run, args.name, summary=args.summary, commands=args.commands, commit=args.commit,
                            machine=args.machine,
                            held_out={"description": args.held_out_description, "figures": figures})
    except SianmsError as error:
        raise SystemExit(f"error: {error}") from None
    print(f"wrote zoo:{card['name']} ({card['bytes']:,} bytes, SHA-256 {card['sha256'][:12]})")


if __name__ == "__main__":
    main()
