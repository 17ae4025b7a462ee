"""Evaluation folders written by hand, as `sianms eval` leaves them when complete, for the report tests, and
an HTML reader of their tables.

Every figure is known (eval.json, table.json, metrics and details files with the fields
`sianms eval` writes); the report of a real evaluation is checked in tests/evaluation/test_eval_job.py.
"""

from __future__ import annotations

import base64
import json
from html.parser import HTMLParser
from pathlib import Path

import numpy as np

from sianms_cli.metrics.algo import NELEM, MetricData
from sianms_cli.metrics.config import load_config
from sianms_cli.metrics.evaluate import write_details
from sianms_cli.reporting.eval_table import PAPER_TABLE_I

METHODS = ("vanilla", "axis-nms", "sianms", "oracle")
CLASSES = ("car", "pedestrian", "bicycle")
PAIR = "overlap:CAM_FRONT|CAM_FRONT_RIGHT"
REGIONS = ("all", "overlap", PAIR)
PNG = base64.b64decode("iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mNkYPhfDwAChwGA60e6kgAAAABJRU5E"
                       "rkJggg==")
CONFIG = {"split": "mini_val", "split_scenes": ["scene-0103", "scene-0916"], "dataset_sha256": "d" * 64,
          "methods": list(METHODS), "nms_sweep": None, "axis_mode": "ignore-yaw", "sianms_classes": ["car"],
          "max_distance": 50.0, "seed": 0, "pictures": 1, "version": "v1.0-mini", "dis_thr": 0.8,
          "cache_sha256": "c" * 64, "siamese_sha256": "s" * 64, "fpointnet_sha256": "f" * 64}


def cell(method: int, region: int, name: str) -> dict:
    """Figures with digits past the printed precision, so formatting is tested too; bicycle has no GT."""
    if name == "bicycle":
        return {"AP": None, "ATE": None, "ASE": None, "AOE": None, "gt": 0, "pred": 3}
    base = 31.2345 + 1.1111 * method - 7.777 * region + (5.5 if name == "pedestrian" else 0.0)
    return {"AP": base, "ATE": 0.61234 + 0.01 * method + 0.1 * region, "ASE": 24.5678 - 0.3 * method,
            "AOE": 1.38123 - 0.01 * method, "gt": 605 - 539 * min(region, 1), "pred": 700 - 20 * method}


def table_of(methods) -> dict:
    return {
        "table_class": "car", "classes": list(CLASSES), "pair_regions": [PAIR],
        "units": {"AP": "%", "ATE": "m", "ASE": "% (1 - IoU)", "AOE": "rad"}, "methods": list(methods),
        "boxes": {m: 1000 - 10 * i for i, m in enumerate(methods)},
        "regions": {region: {m: {name: cell(i, r, name) for name in CLASSES} for i, m in enumerate(methods)}
                    for r, region in enumerate(REGIONS)},
        "best_nms": {"axis-nms": "axis-nms"} if "axis-nms" in methods else {},
        "duplicates": {m: {region: {name: 27 - 5 * i - r for name in CLASSES} for r, region in enumerate(REGIONS)}
                       for i, m in enumerate(methods)},
        "reidentification": {"sianms": {"precision": 0.7123, "recall": 0.8456, "f1": 0.7732, "pairs_matched": 60,
                                        "pairs_correct": 43, "pairs_true": 48, "wrong_without_partner": 13,
                                        "wrong_partner_passed_over": 4, "dismissed": 12, "dismissed_right": 1},
                             "gated-sianms": {"precision": 0.9, "recall": 0.75, "f1": 0.8182, "pairs_matched": 40,
                                              "pairs_correct": 36, "pairs_true": 48, "wrong_without_partner": 3,
                                              "wrong_partner_passed_over": 1, "dismissed": 12, "dismissed_right": 1,
                                              "gate_refused": 20, "gate_refused_right": 7},
                             "oracle": {"precision": 1.0, "recall": 1.0, "f1": 1.0, "pairs_matched": 48,
                                        "pairs_correct": 48, "pairs_true": 48, "dismissed": 3}},
        "paper_table_i": PAPER_TABLE_I,
    }


def curve(scale: float) -> MetricData:
    """A class's 101-point curves: recall reached up to 0.6, precision falling, errors growing."""
    recall = np.linspace(0, 1, NELEM)
    reached = recall <= 0.6
    return MetricData(recall, np.where(reached, 1 - 0.5 * recall, 0), np.where(reached, 1 - recall, 0),
                      *(np.where(reached, scale * (0.2 + recall), 1.0) for _ in range(5)))


def make_eval(folder: Path, *, methods=METHODS, details: bool = False, **config_changes) -> Path:
    """An evaluation folder as `sianms eval` leaves it when complete."""
    folder.mkdir(parents=True)
    config = {**CONFIG, "methods": list(methods), **config_changes}
    marker = {"kind": "sianms-eval", "config": config, "complete": True, "scenes_expected": 2, "scenes_finished": 2,
              "missing_scenes": [], "timings": {"scenes_s": 30.0, "select_vanilla_s": 0.5, "metrics_vanilla_s": 4.5,
                                                "pictures_s": 5.0}}
    (folder / "eval.json").write_text(json.dumps(marker))
    (folder / "table.json").write_text(json.dumps(table_of(methods)))
    for i, method in enumerate(methods):
        (folder / f"metrics_{method}.json").write_text(json.dumps({"schema": "sianms-metrics",
                                                                   "cfg": load_config("paper").serialize()}))
        if details:
            write_details(folder / f"metrics_details_{method}.json",
                          {region: {"car:2.0": curve(1 + 0.1 * i)} for region in ("all", "overlap")})
    (folder / "pictures").mkdir()
    (folder / "pictures" / "sample0.png").write_bytes(PNG)
    return folder


def edit_table(folder: Path, change) -> None:
    table = json.loads((folder / "table.json").read_text())
    change(table)
    (folder / "table.json").write_text(json.dumps(table))


class Cells(HTMLParser):
    """Every <table> of a page as {id: [[cell text, ...], ...]}, and every attribute value seen."""

    def __init__(self) -> None:
        super().__init__()
        self.tables: dict[str, list[list[str]]] = {}
        self.attributes: list[tuple[str, str]] = []
        self.tags: list[str] = []
        self._table = self._row = self._cell = None

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        self.attributes += [(name, value or "") for name, value in attrs]
        if tag == "table":
            self._table = self.tables.setdefault(dict(attrs)["id"], [])
        elif tag == "tr":
            self._row = []
            self._table.append(self._row)
        elif tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag):
        if tag in ("td", "th"):
            self._row.append("".join(self._cell))
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)


def parse_html(path: Path) -> Cells:
    parser = Cells()
    parser.feed(path.read_text())
    return parser
