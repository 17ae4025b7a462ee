"""The cost of a study's worlds, from the costs.jsonl files scripts/zoo_study_world.sh appends to: wall time
of each stage and disk, per world and for the whole study, as a Markdown table.

A line of costs.jsonl is one finished run of one stage (seed, stage, seconds, bytes of its output, finished).
A stage run again after an interruption has a line for each part, and they add up. Disk: *at its peak* is
a world's dataset, caches, siamese run and evaluations together; *kept* is what remains once the dataset
and caches are pruned (the siamese run and the evaluations).

Usage: python scripts/study_costs.py STUDY/s101/costs.jsonl STUDY/s102/costs.jsonl ...
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.io import describe_os_error

STAGES = ("synth", "prepare", "siamese", "eval")
"""Columns: a line's stage is counted under the one its name starts with (prepare-val under prepare)."""
KEPT = ("siamese", "eval")
"""The stages whose output a pruned world keeps."""


def read_costs(path: Path) -> list[dict]:
    """The lines of one costs.jsonl, each checked for the fields the table needs."""
    lines = []
    for number, text in enumerate(path.read_text().splitlines(), start=1):
        try:
            line = json.loads(text)
            if not (isinstance(line["seed"], int) and isinstance(line["stage"], str)
                    and line["seconds"] >= 0 and line["bytes"] >= 0):
                raise ValueError
        except (ValueError, KeyError, TypeError):
            raise DataFormatError(path, f"line {number}: not a costs line (seed, stage, seconds, bytes): "
                                        f"{text[:60]!r}") from None
        lines.append(line)
    return lines


def world_costs(lines: list[dict]) -> dict[int, dict[str, float]]:
    """Per seed: seconds per stage column, total seconds, and bytes at the peak and kept."""
    worlds: dict[int, dict[str, float]] = defaultdict(lambda: defaultdict(float))
    last_bytes: dict[tuple[int, str], int] = {}
    for line in lines:
        column = next((stage for stage in STAGES if line["stage"].startswith(stage)), None)
        if column is None:
            raise SianmsError(f"unknown stage {line['stage'][:40]!r} (seed {line['seed']})")
        worlds[line["seed"]][column] += line["seconds"]
        worlds[line["seed"]]["total"] += line["seconds"]
        last_bytes[line["seed"], line["stage"]] = line["bytes"]  # a later part measures the whole output
    for (seed, stage), size in last_bytes.items():
        worlds[seed]["peak"] += size
        worlds[seed]["kept"] += size if stage.startswith(KEPT) else 0
    return {seed: dict(worlds[seed]) for seed in sorted(worlds)}


def markdown(worlds: dict[int, dict[str, float]]) -> str:
    """The table: one row per world, then the study's total (its disk at the peak: worlds one after another in
    seed order, each pruned once evaluated, as scripts/zoo_study.sh runs them)."""
    header = ("| world | " + " | ".join(f"{stage} (s)" for stage in STAGES)
              + " | total (min) | disk at its peak (GB) | kept (MB) |")
    rows = [header, "|" + "---|" * (len(STAGES) + 4)]
    for seed, cost in worlds.items():
        rows.append(f"| {seed} | " + " | ".join(f"{cost.get(stage, 0):,.0f}" for stage in STAGES)
                    + f" | {cost['total'] / 60:.1f} | {cost['peak'] / 1e9:.1f} | {cost['kept'] / 1e6:.0f} |")
    total = {key: sum(cost.get(key, 0) for cost in worlds.values()) for key in (*STAGES, "total", "kept")}
    kept_before = 0.0
    peak = 0.0
    for cost in worlds.values():  # in seed order, as scripts/zoo_study.sh runs them
        peak = max(peak, kept_before + cost["peak"])
        kept_before += cost["kept"]
    rows.append(f"| all {len(worlds)} | " + " | ".join(f"{total[stage]:,.0f}" for stage in STAGES)
                + f" | {total['total'] / 60:.1f} | {peak / 1e9:.1f} | {total['kept'] / 1e6:.0f} |")
    return "\n".join(rows) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("costs", nargs="+", type=Path, help="costs.jsonl files, one per world")
    args = parser.parse_args()
    try:
        lines = [line for path in args.costs for line in read_costs(path)]
        sys.stdout.write(markdown(world_costs(lines)))
    except (SianmsError, OSError) as error:
        print(f"error: {describe_os_error(error) if isinstance(error, OSError) else error}", file=sys.stderr)
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()
