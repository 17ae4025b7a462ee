"""Making a zoo entry from a finished training run (maintainers: ``scripts/make_zoo_entry.py``).

The entry's checkpoint keeps what inference and fine-tuning read (kind, config, epoch, weights,
history, extra) and drops the optimizer state; floating weights are stored in float16, which
``load_state_dict`` casts back to the model's float32 (buffers stay float32). The model card (:mod:`sianms_cli.zoo`)
records the file's size and SHA-256, so a damaged or replaced file is refused when named.
"""

from __future__ import annotations

import hashlib
import io
import platform
from pathlib import Path
from typing import Any

import torch

from sianms_cli.data.cache import complete_manifest, cache_fingerprint
from sianms_cli.io import write_bytes, write_json
from sianms_cli.provenance import numeric_platform
from sianms_cli.training.run import CHECKPOINT_FORMAT, Checkpoint, checkpoint_file, load_checkpoint
from sianms_cli.zoo import CARD_KIND, FOLDER, PREFIX, is_zoo_name
from sianms_cli.zoo import card as zoo_card

CURVE_FIGURES = ("train_total", "train_heading_class", "val_heading_error", "val_heading_error_mod_pi",
                 "val_heading_bin_accuracy", "val_iou_0.7", "val_car_heading_error", "val_car_iou_0.7",
                 "val_car_center_error", "val_auc", "val_f1")
"""Per-epoch figures a card's training summary keeps (those the run has)."""


def slim_checkpoint(checkpoint: Checkpoint) -> bytes:
    """The bytes of ``checkpoint`` as a zoo entry stores it: no optimizer state, float16 weights and
    biases; buffers (batch-norm statistics, size clusters) stay float32, as inference reads them."""
    model = {key: value.half() if key.endswith((".weight", ".bias")) and value.is_floating_point() else value
             for key, value in checkpoint.model.items()}
    buffer = io.BytesIO()
    torch.save({"format": CHECKPOINT_FORMAT, **{**checkpoint.__dict__, "model": model, "optimizer": {}}}, buffer)
    return buffer.getvalue()


def training_summary(checkpoint: Checkpoint) -> dict[str, Any]:
    """Epochs, wall time and the per-epoch figures of :data:`CURVE_FIGURES` from a run's history;
    for a run started from other weights (``--init``), ``started_from`` holds that training's
    summary in turn (a zoo entry's: its card's), so the card accounts for every epoch behind the
    weights. An ``--init`` path is read relative to the working folder, as the training read it."""
    history = checkpoint.history
    curve = [{"epoch": row["epoch"], **{name: row[name] for name in CURVE_FIGURES if row.get(name) is not None}}
             for row in history]
    summary = {"epochs": checkpoint.epoch,
               "wall_seconds": round(sum(row.get("seconds") or 0.0 for row in history), 1),
               "precision": checkpoint.extra.get("precision", "fp32"), "curve": curve}
    init = checkpoint.config.get("init")
    if init:
        summary["started_from"] = {"init": init, **(zoo_card(init[len(PREFIX):])["training"] if is_zoo_name(init)
                                                     else training_summary(load_checkpoint(checkpoint_file(init))))}
    return summary


def export_entry(run: str | Path, name: str, *, summary: str, commands: list[str], commit: str,
                 held_out: dict[str, Any], machine: str, folder: Path = FOLDER) -> dict[str, Any]:
    """Write ``<name>.pt`` and ``<name>.json`` into ``folder`` from the run folder (or checkpoint)
    ``run`` and return the card. ``held_out``: the figures on data the run never saw, with a
    ``description``; ``machine``: where it trained (CPU or GPU model, threads)."""
    checkpoint = load_checkpoint(checkpoint_file(run))
    data = slim_checkpoint(checkpoint)
    manifest = complete_manifest(checkpoint.config["cache"])
    record = {
        "kind": CARD_KIND, "name": name, "model": checkpoint.kind, "file": f"{name}.pt",
        "sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data), "summary": summary, "commands": commands,
        "commit": commit,
        "dataset": {"dataset_sha256": manifest["config"].get("dataset_sha256"),
                    "cache_fingerprint": cache_fingerprint(manifest), "split": manifest["config"].get("split"),
                    "counts": manifest.get("counts")},
        "training": {**training_summary(checkpoint), "machine": machine, "platform": numeric_platform(),
                     "python": platform.python_version(), "torch": torch.__version__,
                     "config": {key: value for key, value in checkpoint.config.items()
                                if key not in ("cache", "val_cache", "dataroot")}},
        "held_out": held_out,
    }
    write_bytes(folder / f"{name}.pt", data)
    write_json(folder / f"{name}.json", record)
    return record
