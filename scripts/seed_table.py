"""Table I over several runs: mean and sample standard deviation of each car cell.

    python scripts/seed_table.py sianms-demo-s0/eval/report/report.json sianms-demo-s1/... [--md]

Reads the `sianms report` JSON of each run (one per seed), checks that they evaluate the
same methods, and prints, per region (All, Overlap) and method, AP / ATE / ASE / AOE as
mean ± standard deviation over the runs, the ground-truth car count of each run, and the
re-identification precision and recall of siaNMS. The NMS families appear at the paper's
IoU 0.3 and at each run's best threshold (which may differ between runs).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

METHODS = ("vanilla", "axis-nms", "axis-nms (best)", "rotated-nms", "rotated-nms (best)", "circle-nms",
           "sianms", "hybrid", "gated-sianms", "oracle")
MERGING = ("sianms", "hybrid", "gated-sianms", "oracle")  # compared run by run with vanilla and Axis-NMS
UNITS = ("AP", "ATE", "ASE", "AOE")
DIGITS = {"AP": 1, "ATE": 3, "ASE": 1, "AOE": 3}
PAPER = {("all", "vanilla"): (45.5, 0.331, 18.4, 0.371), ("all", "axis-nms"): (49.1, 0.330, 18.4, 0.367),
         ("all", "sianms"): (51.1, 0.320, 18.2, 0.350), ("overlap", "vanilla"): (37.9, 0.317, 18.6, 0.312),
         ("overlap", "axis-nms"): (46.6, 0.312, 18.6, 0.306), ("overlap", "sianms"): (49.0, 0.287, 18.0, 0.253)}


def cell(report: dict, region: str, method: str) -> dict:
    """The car metrics of one method (or "<family> (best)") in one region of a report."""
    if method.endswith(" (best)"):
        method = report["best_nms"][method.removesuffix(" (best)")]
    return report["regions"][region][method]["car"]


def evaluated(reports: list[dict], methods: tuple[str, ...]) -> list[str]:
    """The names of ``methods`` the runs evaluated (an older run may lack a newer method)."""
    return [m for m in methods if m.removesuffix(" (best)") in reports[0]["methods"]]


def paired_differences(reports: list[dict]) -> list[str]:
    """Overlap AP and ATE of the merging methods minus vanilla and Axis-NMS, run by run: the
    runs share their data between methods, so the paired difference is what ranks two
    methods, and its spread is far smaller than the spread of either."""
    lines = ["| overlap, run by run | AP difference (points) | ATE difference (m) |", "|---|---|---|"]
    for method in evaluated(reports, MERGING):
        for reference in ("vanilla", "axis-nms", "axis-nms (best)"):
            texts = []
            for unit in ("AP", "ATE"):
                d = np.array([cell(r, "overlap", method)[unit] - cell(r, "overlap", reference)[unit]
                              for r in reports])
                runs = ", ".join(f"{x:+.{DIGITS[unit]}f}" for x in d)
                texts.append(f"{d.mean():+.{DIGITS[unit]}f} ± {d.std(ddof=1):.{DIGITS[unit]}f} ({runs})")
            lines.append(f"| {method} − {reference} | {texts[0]} | {texts[1]} |")
    return lines


def table(reports: list[dict]) -> list[str]:
    lines = ["| region | method | " + " | ".join(UNITS) + " | paper AP / ATE / ASE / AOE | GT cars per run |",
             "|---|---|" + "---|" * len(UNITS) + "---|---|"]
    for region in ("all", "overlap"):
        for method in evaluated(reports, METHODS):
            cells = [cell(r, region, method) for r in reports]
            values = []
            for unit in UNITS:
                x = np.array([c[unit] for c in cells], float)
                values.append(f"{x.mean():.{DIGITS[unit]}f} ± {x.std(ddof=1):.{DIGITS[unit]}f}")
            paper = PAPER.get((region, method))
            paper_text = " / ".join(f"{v:.{DIGITS[u]}f}" for u, v in zip(UNITS, paper)) if paper else "-"
            gt = ", ".join(str(c["gt"]) for c in cells)
            lines.append(f"| {region.capitalize()} | {method} | " + " | ".join(values) + f" | {paper_text} | {gt} |")
    lines.append("")
    lines += paired_differences(reports)
    lines.append("")
    for matcher, label in (("sianms", "siaNMS"), ("gated-sianms", "Gated siaNMS")):
        if matcher in reports[0]["reidentification"]:
            reid = [r["reidentification"][matcher] for r in reports]
            p = np.array([x["precision"] for x in reid])
            rec = np.array([x["recall"] for x in reid])
            lines.append(f"{label} matches: precision {p.mean():.2f} ± {p.std(ddof=1):.2f}, recall {rec.mean():.2f} ± "
                         f"{rec.std(ddof=1):.2f} (true pairs per run: {', '.join(str(x['pairs_true']) for x in reid)})")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reports", nargs="+", type=Path, help="report.json of each run")
    args = parser.parse_args()
    if len(args.reports) < 2:
        parser.error("give at least two runs: the spread needs them")
    reports = [json.loads(path.read_text()) for path in args.reports]
    methods = {tuple(r["methods"]) for r in reports}
    if len(methods) != 1:
        parser.error("the runs evaluate different methods")
    print("\n".join(table(reports)))


if __name__ == "__main__":
    main()
