"""The run folder every training shares: checkpoint, resolved config, metrics, curves, seeds, device.

Layout of a run folder ``RUN/``::

    config.json      the resolved config (plain JSON), written when the run starts
    checkpoint.pt    after every epoch: weights, optimizer, epochs done, metrics history,
                     the resolved config and what a later stage needs (e.g. dis_thr);
                     plain types and tensors only, so it loads with ``weights_only=True``
    metrics.csv      one row per finished epoch (rewritten from the checkpoint's history)
    curves.png       every numeric column of metrics.csv against the epoch
    .sianms.lock     held while a run writes the folder

Every file is written atomically (hidden temporary name, renamed when complete), so a
killed run leaves the last finished epoch's files, never a half-written one. A run that
fails (an error, not an interrupt) before its first checkpoint removes what it created in
the folder, and the folder when it created it: bad input leaves nothing that looks like a
run and blocks the next one.

How a training uses it (the whole API)::

    run = RunFolder.open(out, kind="siamese", config=asdict(config), overwrite=..., resume=...,
                         may_differ=("epochs", "device"))
    with run:                                   # holds the folder's lock
        seed_everything(config.seed)
        model, optimizer = ...
        start = 0
        if run.resumed is not None:             # --resume found a checkpoint
            run.restore(model, optimizer)
            start = run.resumed.epoch
        for epoch in range(start, config.epochs):
            set_learning_rate(optimizer, step_decay(config.lr, config.lr_decay, config.lr_step, epoch))
            rng = epoch_generator(config.seed, epoch)   # every draw of the epoch comes from it
            ...
            run.save(Checkpoint(kind="siamese", config=run.config, epoch=epoch + 1,
                                model=model.state_dict(), optimizer=optimizer.state_dict(),
                                history=[*history, row], extra={...}))

Resume is exact because nothing random carries over between epochs: each epoch draws
from :func:`epoch_generator` (seed, epoch, rank), the learning rate is a function of the
epoch (:func:`step_decay`), and the optimizer state is in the checkpoint. A run killed
mid-epoch resumes at the start of that epoch and ends bit-for-bit where an uninterrupted
run ends (on a CPU; CUDA kernels may not be deterministic).
"""

from __future__ import annotations

import atexit
import csv
import gc
import hashlib
import io
import json
import math
import os
import random
import shutil
import warnings
from contextlib import AbstractContextManager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
import torch

from sianms_cli.data.cache import cache_fingerprint, verify_cache
from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError
from sianms_cli.json_stream import is_number
from sianms_cli import zoo
from sianms_cli.io import (FolderBusyError, check_regular_file, exclusive_lock, first_foreign_file, make_folder,
                          partial_of, read_json, write_bytes, write_json)

CHECKPOINT = "checkpoint.pt"
CONFIG = "config.json"
METRICS = "metrics.csv"
CURVES = "curves.png"
RUN_FILES = (CHECKPOINT, CONFIG, METRICS, CURVES)
RUN_KINDS = ("siamese", "fpointnet")  # what a run's config.json and checkpoint say they are
FOLDER_LOCK_NAME = ".sianms.lock"
CHECKPOINT_FORMAT = "sianms-checkpoint-1"
_CHECKPOINT_KEYS = {"format", "kind", "config", "epoch", "model", "optimizer", "history", "extra"}


# --------------------------------------------------------------------------- device and seeds


def choose_device(name: str) -> torch.device:
    """``auto`` (CUDA when available, else CPU), ``cpu``, ``cuda`` or ``cuda:N``.

    A CUDA device that is not there is a user error, not a crash deep in the loop.
    """
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except RuntimeError:
        raise SianmsError(f"--device must be auto, cpu, cuda or cuda:N, got '{name}'") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise SianmsError(f"--device {name}: CUDA is not available on this machine")
    if device.type not in ("cpu", "cuda"):
        raise SianmsError(f"--device must be auto, cpu, cuda or cuda:N, got '{name}'")
    return device


def init_distributed(device: torch.device) -> tuple[int, int, torch.device]:
    """(rank, world size, this rank's device); joins torchrun's process group when WORLD_SIZE > 1.

    Under ``torchrun --nproc-per-node K`` each process trains on its share of every global
    batch with DistributedDataParallel (gloo on CPUs, NCCL on GPUs; CUDA rank r uses
    ``cuda:LOCAL_RANK``). Rank 0 alone validates and writes the run folder.
    """
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return 0, 1, device
    import torch.distributed as dist

    if device.type == "cuda":
        device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
        torch.cuda.set_device(device)
    if not dist.is_initialized():
        dist.init_process_group(backend="nccl" if device.type == "cuda" else "gloo")
        atexit.register(leave_process_group)
    return dist.get_rank(), dist.get_world_size(), device


def leave_process_group() -> None:
    """Free what still holds the process group, then destroy it, while the interpreter is whole (at exit).

    A DistributedDataParallel wrapper can sit in a reference cycle (it did in a fresh process), so
    it and the group it holds outlive their training until the cyclic collector runs. Left to
    interpreter shutdown, a gloo worker thread still finishing a work then needs the GIL to drop
    the work's Python state, and the rank aborts ("terminate called without an active exception",
    seen under gdb). A minimal two-rank script that trains twice and exits aborted in 3 of 45 runs
    with the group destroyed alone and in 0 of 90 with the collector run first.
    """
    import torch.distributed as dist

    gc.collect()
    dist.destroy_process_group()


def writes_outputs() -> bool:
    """Whether this process writes a run's files: a single process, or rank 0 of a distributed run."""
    import torch.distributed as dist

    return not (dist.is_available() and dist.is_initialized()) or dist.get_rank() == 0


def finish_distributed(world: int) -> None:
    """Wait for every rank before the process group is torn down at exit. Rank 0 validates and
    writes after the last epoch; a rank that left at once tore the group down under it and
    could abort ("terminate called without an active exception": the 2-process test failed
    so once on a fresh clone)."""
    if world > 1:
        import torch.distributed as dist

        dist.barrier()


def sum_over_ranks(values: Sequence[float], device: torch.device, world: int) -> list[float]:
    """Element-wise sums of ``values`` over every rank (``values`` itself in one process).

    Reduced on the training device (NCCL reduces CUDA tensors only), in float64 (exact for
    counts below 2**53).
    """
    if world <= 1:
        return list(values)
    import torch.distributed as dist

    tensor = torch.tensor(values, dtype=torch.float64, device=device)
    dist.all_reduce(tensor)
    return tensor.tolist()


def row_counts(count: int, rank: int, world: int, device: torch.device) -> list[int]:
    """Every rank's row count of a step, from this rank's ``count``."""
    return [int(value) for value in sum_over_ranks([count if other == rank else 0 for other in range(world)],
                                                  device, world)]


def seed_everything(seed: int, rank: int = 0) -> None:
    """Seed Python's, numpy's global and torch's (CPU and CUDA) generators with ``seed + rank``.

    Model initialisation draws from torch's generator, so the same seed gives the same
    initial weights; per-epoch sampling uses :func:`epoch_generator` instead.
    """
    random.seed(seed + rank)
    np.random.seed((seed + rank) % 2**32)
    torch.manual_seed(seed + rank)


def epoch_generator(seed: int, epoch: int, rank: int = 0) -> np.random.Generator:
    """The generator of every random draw of one epoch on one rank.

    Derived from (seed, epoch, rank) alone, so a resumed run draws exactly what an
    uninterrupted run draws, without saving generator state.
    """
    return np.random.default_rng([seed, epoch, rank])


def step_decay(lr: float, gamma: float, step: int, epoch: int) -> float:
    """Learning rate of ``epoch`` (0-based): ``lr * gamma ** (epoch // step)`` (paper: 1e-4, 0.1, 8)."""
    return lr * gamma ** (epoch // step)


def set_learning_rate(optimizer: torch.optim.Optimizer, lr: float) -> None:
    """Set every parameter group's learning rate (the schedule is a function of the epoch)."""
    for group in optimizer.param_groups:
        group["lr"] = lr


# --------------------------------------------------------------------------- checkpoints


@dataclass
class Checkpoint:
    """What ``checkpoint.pt`` holds; plain types and tensors only.

    Attributes:
        kind: the model ("siamese", "fpointnet"); loading checks it.
        config: the resolved config (JSON-able dict).
        epoch: epochs finished.
        model, optimizer: their ``state_dict()``.
        history: one dict of figures per finished epoch (the rows of metrics.csv).
        extra: what later stages read (e.g. ``dis_thr``); plain types and tensors.
    """

    kind: str
    config: dict[str, Any]
    epoch: int
    model: dict[str, Any]
    optimizer: dict[str, Any] = field(default_factory=dict)
    history: list[dict[str, Any]] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)


def save_checkpoint(path: str | Path, checkpoint: Checkpoint) -> Path:
    """Write ``checkpoint`` atomically to ``path``."""
    buffer = io.BytesIO()
    torch.save({"format": CHECKPOINT_FORMAT, **checkpoint.__dict__}, buffer)
    return write_bytes(path, buffer.getvalue())


def checkpoint_file(run: str | Path) -> Path:
    """The checkpoint of ``run``: a run folder's ``checkpoint.pt``, ``run`` itself when it names a
    file, or a zoo entry's checked file for ``zoo:NAME`` (:mod:`sianms_cli.zoo`)."""
    if zoo.is_zoo_name(run):
        return zoo.checkpoint_path(run)
    path = Path(run)
    return path / CHECKPOINT if path.is_dir() else path


def load_checkpoint(path: str | Path, kind: str | None = None) -> Checkpoint:
    """Read a checkpoint with ``torch.load(weights_only=True)``: nothing is unpickled as code.

    A missing file, a file that is not a sianms checkpoint (a pickled object, other keys,
    another model's ``kind``) raises DataFormatError naming the file and what is wrong.
    """
    path = Path(path)
    if path.is_dir():
        raise DataFormatError(path, "is a folder, not a checkpoint file")
    check_regular_file(path)  # "file not found", or a FIFO or a device, refused before torch reads it
    try:
        with warnings.catch_warnings():  # torch warns of a foreign pickle protocol before refusing it: say it once
            warnings.simplefilter("ignore", UserWarning)
            data = torch.load(path, map_location="cpu", weights_only=True)
    except PermissionError as error:
        raise DataFormatError(path, f"cannot read: {error.strerror}") from None
    except Exception as error:  # torch's zip and pickle readers raise almost any exception on damaged bytes
        raise DataFormatError(path, f"not a sianms checkpoint (weights-only load refused it: "
                              f"{_refusal_reason(error)})") from None
    if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
        raise DataFormatError(path, f"not a sianms checkpoint (no format '{CHECKPOINT_FORMAT}')", field="format")
    foreign = sorted(set(data) - _CHECKPOINT_KEYS)
    missing = sorted(_CHECKPOINT_KEYS - set(data))
    if foreign or missing:
        what = "; ".join(part for part in (f"unexpected keys {foreign}" if foreign else "",
                                           f"missing keys {missing}" if missing else "") if part)
        raise DataFormatError(path, f"not a sianms checkpoint: {what}")
    for key, wanted in _CHECKPOINT_TYPES.items():
        if not isinstance(data[key], wanted) or isinstance(data[key], bool):
            raise DataFormatError(path, f"expected {_TYPE_NAMES[wanted]}, got {type(data[key]).__name__}", field=key)
    if data["epoch"] < 0:
        raise DataFormatError(path, f"expected an epoch count >= 0, got {data['epoch']}", field="epoch")
    if kind is not None and data["kind"] != kind:
        raise DataFormatError(path, f"a '{data['kind']}' checkpoint, expected '{kind}'", field="kind")
    for name, value in data["model"].items():
        if not isinstance(value, torch.Tensor):
            raise DataFormatError(path, f"expected a tensor, got {type(value).__name__}", field=f"model.{name}")
    _refuse_non_finite(path, data)
    for i, row in enumerate(data["history"]):
        if not isinstance(row, dict):
            raise DataFormatError(path, f"expected an object per epoch, got {type(row).__name__}",
                                  field=f"history[{i}]")
        if row.get("epoch") != i + 1 or type(row["epoch"]) is not int:  # metrics.csv and the curves go by it
            raise DataFormatError(path, f"expected {i + 1}, got {row.get('epoch')!r}", field=f"history[{i}].epoch")
        for name, value in row.items():  # every figure a training writes is a number, or null where none
            if not (value is None or is_number(value)):
                raise DataFormatError(path, f"expected a number or null, got {type(value).__name__}",
                                      field=f"history[{i}].{name}")
    del data["format"]
    return Checkpoint(**data)


def _refuse_non_finite(path: Path, data: dict[str, Any]) -> None:
    """Refuse a checkpoint whose weights (or optimizer state) hold NaN or infinity, naming the tensor: the
    networks would turn every box into NaN, and an evaluation had blamed its own scene file for it."""
    state = data["optimizer"].get("state") if isinstance(data["optimizer"].get("state"), dict) else {}
    tensors = [(f"model.{name}", value) for name, value in data["model"].items()]
    tensors += [(f"optimizer.state.{key}.{name}", value) for key, values in state.items()
                if isinstance(values, dict) for name, value in values.items() if isinstance(value, torch.Tensor)]
    for name, value in tensors:
        if value.is_floating_point() or value.is_complex():
            finite = torch.isfinite(value)
            if not bool(finite.all()):
                raise DataFormatError(path, f"{int((~finite).sum()):,} of its {value.numel():,} values are NaN or "
                                            "infinite (a training that diverged, or an altered file): not a usable "
                                            "checkpoint; take an earlier one or train again", field=name)


_CHECKPOINT_TYPES = {"kind": str, "config": dict, "epoch": int, "model": dict, "optimizer": dict, "history": list,
                     "extra": dict}
_TYPE_NAMES = {str: "a string", dict: "an object", int: "an integer", list: "a list"}


def _refusal_reason(error: Exception) -> str:
    """The line of a torch.load error that says what was wrong with the bytes (not torch's
    advice to load them as code)."""
    if isinstance(error, OSError) and error.strerror:
        return error.strerror
    text = str(error).strip()
    detail = text.partition("WeightsUnpickler error:")[2].strip()
    return (detail or text).splitlines()[0] if (detail or text) else type(error).__name__


RECORDED_PATHS = ("cache", "val_cache", "dataroot")
"""Config fields that say where a run's inputs lay: recorded for people, left out of its fingerprint."""


def checkpoint_fingerprint(checkpoint: Checkpoint) -> str:
    """Hex SHA-256 of what a checkpoint gives the stages that load it: its kind, config (without
    the paths of :data:`RECORDED_PATHS`), epoch, weights and extra; not the optimizer or history.
    The same training run in another folder, or on caches that moved, keeps its fingerprint."""
    digest = hashlib.sha256()
    config = {key: value for key, value in checkpoint.config.items() if key not in RECORDED_PATHS}
    _digest_value(digest, {"kind": checkpoint.kind, "config": config, "epoch": checkpoint.epoch,
                           "model": checkpoint.model, "extra": checkpoint.extra})
    return digest.hexdigest()


def _digest_value(digest: Any, value: Any) -> None:
    """Feed a checkpoint's plain value (dicts, lists, tensors, JSON scalars) to ``digest``, each
    part tagged with its type and size (a tensor's dtype and shape), so that a reshaped or recast
    tensor, or a value moved between nesting levels, changes the fingerprint."""
    if isinstance(value, torch.Tensor):
        flat = value.detach().cpu().reshape(-1).contiguous()
        digest.update(f"tensor {flat.dtype} {tuple(value.shape)}\0".encode())
        digest.update(flat.view(torch.uint8).numpy().tobytes())
    elif isinstance(value, dict):
        digest.update(f"dict {len(value)}\0".encode())
        for key in sorted(value, key=str):
            digest.update(f"{key!s}\0".encode())
            _digest_value(digest, value[key])
    elif isinstance(value, (list, tuple)):
        digest.update(f"list {len(value)}\0".encode())
        for item in value:
            _digest_value(digest, item)
    else:
        digest.update(f"value {json.dumps(value, sort_keys=True)}\0".encode())


def load_state(module: torch.nn.Module, state: dict[str, Any], path: str | Path) -> None:
    """``module.load_state_dict(state)`` strictly; a key or shape mismatch names the key and the file."""
    own = module.state_dict()
    for key in own:
        if key not in state:
            raise DataFormatError(path, "weights do not fit this model (another config?)", field=f"model.{key}")
    for key, value in state.items():
        if key not in own:
            raise DataFormatError(path, "unexpected weight (another model or config?)", field=f"model.{key}")
        if tuple(value.shape) != tuple(own[key].shape):
            raise DataFormatError(path, f"shape {tuple(value.shape)}, this model has {tuple(own[key].shape)}",
                                  field=f"model.{key}")
    module.load_state_dict(state)


# --------------------------------------------------------------------------- metrics and curves


def metrics_csv(history: Iterable[dict[str, Any]]) -> str:
    """CSV text of the history: one row per epoch, columns in order of first appearance."""
    rows = list(history)
    columns: list[str] = []
    for row in rows:
        columns += [key for key in row if key not in columns]
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({key: _csv_value(row.get(key)) for key in columns})
    return text.getvalue()


def _csv_value(value: Any) -> Any:
    """Floats with full precision (repr), NaN and missing as empty cells."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    return repr(value) if isinstance(value, float) else value


def plot_curves(history: list[dict[str, Any]], path: str | Path, title: str = "",
                panels: Sequence[tuple[str, Sequence[str]]] | None = None) -> Path:
    """curves.png: figures of the history against the epoch.

    ``panels``: (title, columns drawn together) per panel; None draws every numeric column
    in its own panel. Columns missing from the history are skipped. matplotlib is imported
    here, with the Agg backend, so nothing else pays for it.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    numeric = [key for key in (history[0] if history else {}) if key != "epoch"
               and all(isinstance(row.get(key), (int, float)) for row in history)]
    if panels is None:
        panels = [(name, [name]) for name in numeric]
    panels = [(name, [c for c in columns if c in numeric]) for name, columns in panels]
    panels = [(name, columns) for name, columns in panels if columns]
    width = 3
    height = max(1, math.ceil(len(panels) / width))
    figure, axes = plt.subplots(height, width, figsize=(4 * width, 2.8 * height), squeeze=False)
    epochs = [row["epoch"] for row in history]
    for axis, (name, columns) in zip(axes.flat, panels):
        for column in columns:
            axis.plot(epochs, [row[column] for row in history], marker="o", markersize=3, label=column)
        axis.set_title(name, fontsize=9)
        axis.set_xlabel("epoch", fontsize=8)
        axis.grid(alpha=0.3)
        if len(columns) > 1:
            axis.legend(fontsize=7)
    for axis in list(axes.flat)[len(panels):]:
        axis.axis("off")
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=80)
    plt.close(figure)
    return write_bytes(path, buffer.getvalue())


# --------------------------------------------------------------------------- the folder


class RunFolder:
    """One run's folder: refuses to clobber, resumes, writes every epoch atomically.

    Build with :meth:`open`; use as a context manager to hold the folder's lock (a second
    run into the same folder fails at once instead of interleaving checkpoints).
    """

    def __init__(self, path: Path, kind: str, config: dict[str, Any], resumed: Checkpoint | None,
                 write: bool = True, replace: bool = False, inputs: dict[str, str] | None = None) -> None:
        self.path, self.kind, self.config, self.resumed, self.write = path, kind, config, resumed, write
        self.inputs = inputs  # the caches' fingerprints, kept in each checkpoint's extra
        self.replace = replace  # delete the run files found in the folder once its lock is held
        self.panels: Sequence[tuple[str, Sequence[str]]] | None = None  # curves.png layout (plot_curves)
        self._lock: AbstractContextManager[None] | None = None  # the folder's lock, held while the run writes
        self._made_folder = False  # this run created the folder
        self._found: set[str] = set()  # the folder's entries before this run wrote any
        self._saved = False  # this run wrote a checkpoint
        self._history: list[dict[str, Any]] = resumed.history if resumed is not None else []  # the latest checkpoint's

    @property
    def checkpoint_path(self) -> Path:
        return self.path / CHECKPOINT

    @classmethod
    def open(cls, out: str | Path, *, kind: str, config: dict[str, Any], overwrite: bool = False,
             resume: bool = False, may_differ: Iterable[str] = (), added: Mapping[str, Any] | None = None,
             write: bool = True, inputs: dict[str, str] | None = None) -> RunFolder:
        """Check ``out`` and return its folder; read its checkpoint when resuming.

        - A folder holding a run (:func:`holds_run`) is refused unless ``resume`` (continue it:
          its config must equal ``config`` except the fields in ``may_differ`` and the paths of
          :data:`RECORDED_PATHS`, whose content ``inputs`` checks) or ``overwrite``
          (its run files are deleted once the folder's lock is held; nothing else is touched).
        - ``added``: settings introduced after runs were made, each with the value a run that does not
          record it had, so such a run resumes when given that value.
        - ``resume`` with no checkpoint yet starts afresh, when config.json gives the same config.
        - A non-empty folder that holds no run is refused, ``overwrite`` or not: it is someone else's.
        - ``write`` false (the non-zero ranks of a distributed run): check and read only.
        - ``inputs`` (:func:`cache_inputs`) go into every checkpoint, and a resumed run's must be
          equal: a cache prepared anew at the same path would mix two trainings in one.
        """
        path = Path(out)
        if resume and overwrite:
            raise SianmsError("--resume continues the run in the folder and --overwrite starts it afresh: pass one")
        if not write:  # rank 0 checks and may be writing config.json already: only read the checkpoint
            resumed = load_checkpoint(path / CHECKPOINT, kind) if resume and (path / CHECKPOINT).exists() else None
            _check_inputs(path, resumed, inputs)
            return cls(path, kind, config, resumed, write, inputs=inputs)
        if path.exists() and not path.is_dir():
            raise OutputExistsError(f"{path} exists and is not a folder; choose another --out")
        has_run = path.is_dir() and holds_run(path)
        if path.is_dir() and not has_run and any(not _is_left_by_a_start(p.name) for p in path.iterdir()):
            raise OutputExistsError(f"{path} is a non-empty folder that holds no sianms run; choose another --out")
        resumed = None
        if has_run and resume:
            wanted = {"kind": kind, **config}  # as config.json holds it
            if (path / CHECKPOINT).exists():
                resumed = load_checkpoint(path / CHECKPOINT, kind)
                stored = {"kind": kind, **resumed.config}
            else:  # a run stopped in its first epoch: its config.json says what it was
                stored = _stored_config(path / CONFIG)
            stored = {**(added or {}), **stored}
            # Where the caches lie may differ ("c" and "./c", or moved): their content is checked below.
            differ = sorted(key for key in set(wanted) | set(stored)
                            if key not in {*may_differ, *RECORDED_PATHS} and wanted.get(key) != stored.get(key))
            if differ:
                raise SianmsError(f"cannot resume {path}: the config differs in {', '.join(differ)} "
                                  "(pass the same options, or --overwrite to start afresh)")
            _check_inputs(path, resumed, inputs)
        elif has_run and not overwrite:
            raise OutputExistsError(f"{path} holds a run; pass --resume to continue it or --overwrite to replace it")
        return cls(path, kind, config, resumed, write, replace=has_run and overwrite, inputs=inputs)

    def __enter__(self) -> RunFolder:
        if self.write:
            self._made_folder = not self.path.is_dir()
            make_folder(self.path)
            self._found = {entry.name for entry in self.path.iterdir()}
            lock = exclusive_lock(self.path / FOLDER_LOCK_NAME, what=str(self.path))
            try:
                lock.__enter__()
            except FolderBusyError:  # the other run's files are not this one's to clean up
                raise
            except Exception:  # a full disk: the lock left no file, so the folder is all this run made
                self._remove_folder_if_made()
                raise
            self._lock = lock
            try:
                if self.replace:  # only now: a run still writing here holds the lock, and keeps its files
                    folder = next((self.path / name for name in RUN_FILES if (self.path / name).is_dir()), None)
                    if folder is not None:  # checked before any deletion: the run's files stay as they were
                        raise OutputExistsError(f"{folder} is a folder where the run writes a file; remove it "
                                                "yourself or choose another --out")
                    for name in RUN_FILES:
                        (self.path / name).unlink(missing_ok=True)
                    self._found -= set(RUN_FILES)
                write_json(self.path / CONFIG, {"kind": self.kind, **self.config})
            except BaseException as error:
                self.__exit__(type(error), error, error.__traceback__)
                raise
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if self._lock is None:
            return
        # An interrupt keeps the folder: --resume restarts it and reuses what it computed.
        failed_early = (exc_type is not None and issubclass(exc_type, Exception) and self.resumed is None
                        and not self._saved)
        lock, self._lock = self._lock, None
        try:
            if failed_early:
                self._remove_created()
            elif exc_type is None:
                self._complete_epoch_files()
        finally:
            lock.__exit__(exc_type, *exc)

    def _complete_epoch_files(self) -> None:
        """metrics.csv and curves.png of the latest checkpoint, where an interrupt between writing
        it and them left them behind it (a resume with no epoch left to train runs only this).
        curves.png is redrawn when it is missing or older than the checkpoint: an interrupt while
        the last epoch's were drawn leaves those of an earlier epoch."""
        if not self._history:
            return
        write_bytes(self.path / METRICS, metrics_csv(self._history).encode())
        curves = self.path / CURVES
        if not curves.is_file() or curves.stat().st_mtime_ns < self.checkpoint_path.stat().st_mtime_ns:
            self._plot()

    def _plot(self) -> None:
        plot_curves(self._history, self.path / CURVES, title=f"{self.kind}: {self.path.name}", panels=self.panels)

    def _remove_created(self) -> None:
        """Delete the folder's entries that were not there when this run started (its lock file
        included), and the folder itself when this run made it."""
        for entry in self.path.iterdir():
            if entry.name not in self._found:
                if entry.is_dir() and not entry.is_symlink():
                    shutil.rmtree(entry)
                else:
                    entry.unlink()
        self._remove_folder_if_made()

    def _remove_folder_if_made(self) -> None:
        if self._made_folder:
            try:
                self.path.rmdir()
            except OSError:  # something else appeared in it: not ours to delete
                pass

    def restore(self, model: torch.nn.Module, optimizer: torch.optim.Optimizer) -> None:
        """Load the resumed checkpoint's weights into ``model`` and its state into ``optimizer``;
        what does not fit names the checkpoint and the field."""
        assert self.resumed is not None, "restore() is for a resumed run"
        if len(self.resumed.history) != self.resumed.epoch:  # a resume would go on from an epoch it has no row of
            raise DataFormatError(self.checkpoint_path, f"{self.resumed.epoch} epochs done, but the history holds "
                                                        f"{len(self.resumed.history)} rows", field="epoch")
        load_state(model, self.resumed.model, self.checkpoint_path)
        try:
            optimizer.load_state_dict(self.resumed.optimizer)
        except (KeyError, TypeError, ValueError, RuntimeError) as error:
            raise DataFormatError(self.checkpoint_path, f"the optimizer state does not fit this model ({error})",
                                  field="optimizer") from None
        _check_optimizer_shapes(optimizer, self.checkpoint_path)

    def save(self, checkpoint: Checkpoint, *, curves: bool = True) -> None:
        """Write the epoch's checkpoint, then metrics.csv and (``curves``) curves.png from its history.

        The checkpoint goes first: metrics.csv never lists an epoch a resume would redo.
        Drawing costs about a second, so a training draws at its last epoch only.
        """
        if not self.write:
            return
        if self.inputs is not None:
            checkpoint = replace(checkpoint, extra={**checkpoint.extra, INPUTS: self.inputs})
        save_checkpoint(self.checkpoint_path, checkpoint)
        self._saved, self._history = True, checkpoint.history
        write_bytes(self.path / METRICS, metrics_csv(checkpoint.history).encode())
        if curves and checkpoint.history:
            self._plot()


def _is_left_by_a_start(name: str) -> bool:
    """The folder lock, or the temporary file of a run file whose write a kill cut short: what a run
    stopped as it started leaves, which does not make the folder someone else's."""
    return name == FOLDER_LOCK_NAME or partial_of(name) in RUN_FILES


def _check_optimizer_shapes(optimizer: torch.optim.Optimizer, path: Path) -> None:
    """Name a loaded optimizer state whose per-weight tensors (Adam's moments) are not their weights'
    shape: torch loads them as they are, and the first step would end in a size-mismatch traceback."""
    weights = (weight for group in optimizer.param_groups for weight in group["params"])
    for index, weight in enumerate(weights):
        for name, value in optimizer.state.get(weight, {}).items():
            if torch.is_tensor(value) and value.dim() and value.shape != weight.shape:
                raise DataFormatError(path, f"state {index} '{name}' has shape {tuple(value.shape)}, its weight "
                                            f"{tuple(weight.shape)} (another config?)", field="optimizer")


def check_losses_finite(row: dict[str, Any]) -> None:
    """Stop a training whose epoch ended on a non-finite loss (a learning rate far too high, or a
    resumed checkpoint with non-finite weights): its weights are no longer numbers, and going on
    would end in a traceback in validation or in a checkpoint that eval cannot use."""
    bad = next((key for key, value in row.items()
                if key.startswith("train_") and isinstance(value, float) and not math.isfinite(value)), None)
    if bad is not None:
        raise SianmsError(f"training diverged in epoch {row['epoch']}: {bad} is {row[bad]} at learning rate "
                          f"{row['lr']:g}; start afresh (--overwrite) with a lower --lr")


INPUTS = "inputs"  # a checkpoint's extra: the content fingerprints of the caches it was trained on


def cache_inputs(cache: str | None, val_cache: str | None) -> dict[str, str]:
    """The content fingerprints of a training's caches, by flag (:func:`cache_fingerprint`), each cache's
    folder checked against its manifest first (:func:`~sianms_cli.data.cache.verify_cache`: the listing and
    sizes; each dataset's digests when a reader first takes its files, before the first epoch)."""
    return {flag: cache_fingerprint(verify_cache(path, ()))
            for flag, path in (("--cache", cache), ("--val-cache", val_cache)) if path is not None}


def _check_inputs(path: Path, resumed: Checkpoint | None, inputs: dict[str, str] | None) -> None:
    """Refuse to resume a run on caches whose content changed since its last checkpoint (a
    checkpoint from before fingerprints were kept is taken as it is)."""
    stored = resumed.extra.get(INPUTS) if resumed is not None and isinstance(resumed.extra, dict) else None
    if inputs is None or not isinstance(stored, dict):
        return
    changed = [flag for flag in sorted(set(inputs) | set(stored)) if inputs.get(flag) != stored.get(flag)]
    if changed:
        raise SianmsError(f"cannot resume {path}: the content of {' and '.join(changed)} changed since the run began "
                          "(prepared anew?); pass the caches it began on, or --overwrite to start afresh")


def foreign_run_entry(path: Path) -> Path | None:
    """The first entry of a run folder that no training writes, or None: what deleting the folder
    would take of someone else's."""
    return first_foreign_file(path, lambda entry: entry.name in RUN_FILES or _is_left_by_a_start(entry.name))


def holds_run(path: Path) -> bool:
    """Whether the folder ``path`` holds a sianms training run, which ``--overwrite`` may replace:
    its config.json is a JSON object of a training kind (:data:`RUN_KINDS`) or, without a
    config.json, its checkpoint.pt is a sianms checkpoint. Anything else by those names is
    someone else's."""
    if (path / CONFIG).is_file():
        try:
            stored = read_json(path / CONFIG)
        except DataFormatError:
            return False
        return isinstance(stored, dict) and stored.get("kind") in RUN_KINDS
    if (path / CHECKPOINT).is_file():
        try:
            load_checkpoint(path / CHECKPOINT)
        except DataFormatError:
            return False
        return True
    return False


def _stored_config(path: Path) -> dict[str, Any]:
    """The config.json of a run that has no checkpoint yet (kind included)."""
    stored = read_json(path)
    if not isinstance(stored, dict):
        raise DataFormatError(path, "not a sianms run config (expected a JSON object)")
    return stored


def plain(value: Any) -> Any:
    """``value`` with tuples as lists and paths as strings: what JSON and weights-only loading keep."""
    if isinstance(value, dict):
        return {str(key): plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(item) for item in value]
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return value
