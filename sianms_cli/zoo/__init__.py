"""The model zoo: networks trained by sianms's own commands, shipped inside the package.

Each entry is two files in this folder: ``<name>.pt``, a sianms checkpoint (no optimizer
state, weights stored in float16 and restored to float32 by ``load_state_dict``), and
``<name>.json``, its model card: what it is, the exact commands that made it, the commit, the
dataset fingerprint, wall time and machine, the training curves' summary and the figures on
a held-out world (docs/model_zoo.md). ``zoo:<name>`` names an entry wherever a run folder or a
checkpoint is accepted; the file is checked against the card's SHA-256 before it is read.

Stdlib only: ``sianms zoo`` lists the entries without importing torch.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from sianms_cli.errors import DataFormatError, SianmsError, shorten

PREFIX = "zoo:"
FOLDER = Path(__file__).resolve().parent
CARD_KIND = "sianms-zoo-entry"
CARD_FIELDS = {"kind": str, "name": str, "model": str, "file": str, "sha256": str, "bytes": int, "summary": str,
               "commands": list, "commit": str, "dataset": dict, "training": dict, "held_out": dict}
"""What every model card holds, and the type of each field."""


def is_zoo_name(spec: str | Path) -> bool:
    """Whether ``spec`` (a flag's value) names a zoo entry rather than a path."""
    return str(spec).startswith(PREFIX)


def names() -> list[str]:
    """The entries shipped, sorted."""
    return sorted(path.stem for path in FOLDER.glob("*.json"))


def card(name: str) -> dict[str, Any]:
    """The model card of entry ``name`` (checked field by field); an unknown name is a user error."""
    path = FOLDER / f"{name}.json"
    if not name or "/" in name or not path.is_file():
        known = ", ".join(f"{PREFIX}{known}" for known in names()) or "none"
        raise SianmsError(f"{PREFIX}{shorten(name, 80)}: no such zoo entry (shipped: {known}; `sianms zoo` lists them)")
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise DataFormatError(path, f"not a readable model card ({error})") from None
    if not isinstance(record, dict) or record.get("kind") != CARD_KIND:
        raise DataFormatError(path, f"not a sianms model card (kind must be '{CARD_KIND}')", field="kind")
    for field, wanted in CARD_FIELDS.items():
        if not isinstance(record.get(field), wanted) or isinstance(record.get(field), bool):
            raise DataFormatError(path, f"expected {wanted.__name__}, got {type(record.get(field)).__name__}",
                                  field=field)
    if record["name"] != name:
        raise DataFormatError(path, f"names entry '{shorten(record['name'], 80)}', not '{name}'", field="name")
    return record


def checkpoint_path(spec: str | Path) -> Path:
    """The checked checkpoint file of ``zoo:NAME``: refused, naming the file, when its size or
    SHA-256 is not the card's (a damaged or replaced file)."""
    name = str(spec)[len(PREFIX):]
    record = card(name)
    path = FOLDER / record["file"]
    if Path(record["file"]).name != record["file"] or not path.is_file():
        raise DataFormatError(FOLDER / f"{name}.json", f"its checkpoint {shorten(record['file'], 80)} is not in "
                              f"{FOLDER}: reinstall sianms", field="file")
    data = path.read_bytes()
    if len(data) != record["bytes"] or hashlib.sha256(data).hexdigest() != record["sha256"]:
        raise DataFormatError(path, f"damaged: {len(data):,} bytes of SHA-256 {hashlib.sha256(data).hexdigest()[:12]}, "
                              f"the model card says {record['bytes']:,} bytes of {record['sha256'][:12]}; "
                              "reinstall sianms")
    return path
