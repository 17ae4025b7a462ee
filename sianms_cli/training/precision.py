"""Mixed precision for both trainings: the float type the training forward passes compute in.

``--precision``:

- ``fp32``: every operation in float32; resume is bit-exact on a CPU.
- ``bf16``: the training forward passes under ``torch.autocast`` with bfloat16 (matrix
  products in bfloat16, accumulated in float32). bfloat16 has float32's exponent range, so
  gradients need no loss scaling. Fast only where the CPU computes bfloat16 in hardware
  (AVX512-BF16 or AMX) *and* the libraries run their native kernels
  (:mod:`sianms_cli.kernels`); anywhere else bfloat16 is emulated, many times slower than
  float32, and is refused (:func:`cpu_bf16_is_native`).
- ``fp16``: autocast with float16 and dynamic loss scaling (``torch.amp.GradScaler``: float16
  gradients underflow otherwise); CUDA only (on a CPU it is slower than float32).
- ``auto``: on CUDA bfloat16 where the GPU has it (Ampere and later), else float16; on a CPU
  bfloat16 where it is native, else float32.

Weights, optimizer state, batch-norm statistics and the losses stay float32 in every mode
(outputs are cast back before the loss: autocast on a CPU leaves sums and norms in
bfloat16). Validation runs in float32, as ``sianms eval`` does, so a run's validation
figures measure its weights, not its arithmetic. Speeds: docs/performance.md.
"""

from __future__ import annotations

import contextlib
import os
from typing import Any

import torch

from sianms_cli.errors import SianmsError
from sianms_cli.kernels import has_native_bf16

PRECISIONS = ("auto", "fp32", "bf16", "fp16")
_DTYPES = {"bf16": torch.bfloat16, "fp16": torch.float16}


def check_precision(name: str) -> None:
    """Refuse a ``--precision`` that is not one of :data:`PRECISIONS`."""
    if name not in PRECISIONS:
        raise SianmsError(f"--precision must be one of {', '.join(PRECISIONS)}, got '{name}'")


def resolve_precision(name: str, device: torch.device) -> str:
    """``fp32``, ``bf16`` or ``fp16``: what ``--precision name`` means on ``device`` (module docstring).

    A mode the device cannot run usefully is a user error: float16 on a CPU, bfloat16 on a
    GPU without it.
    """
    check_precision(name)
    if name == "auto":
        if device.type != "cuda":
            return "bf16" if cpu_bf16_is_native() else "fp32"
        return "bf16" if torch.cuda.is_bf16_supported() else "fp16"
    if name == "fp16" and device.type != "cuda":
        raise SianmsError("--precision fp16 runs on CUDA only (float16 on a CPU is several times slower "
                          "than float32); on a CPU use bf16 or fp32")
    if name == "bf16" and device.type == "cpu" and not cpu_bf16_is_native():
        raise SianmsError("--precision bf16: this CPU would emulate bfloat16 (no AVX512-BF16 or AMX, or the "
                          "libraries run AVX2 kernels), many times slower than fp32; use fp32, or "
                          "SIANMS_NATIVE_KERNELS=1 on a CPU that has them")
    if name == "bf16" and device.type == "cuda" and not torch.cuda.is_bf16_supported():
        raise SianmsError(f"--precision bf16: {torch.cuda.get_device_name(device)} has no bfloat16; use fp16")
    return name


def cpu_bf16_is_native() -> bool:
    """Whether bfloat16 matrix products run in hardware here: the CPU has AVX512-BF16 or AMX, torch
    runs its AVX-512 kernels and oneDNN is not held below them (:mod:`sianms_cli.kernels`)."""
    onednn_limit = os.environ.get("ONEDNN_MAX_CPU_ISA", "ALL").upper()
    return (has_native_bf16() and torch.backends.cpu.get_cpu_capability().startswith("AVX512")
            and (onednn_limit == "ALL" or onednn_limit.startswith(("AVX512_CORE_BF16", "AVX512_CORE_AMX",
                                                                   "AVX10"))))


class MixedPrecision:
    """The autocast context and the backward-and-step of one resolved precision on one device type.

    In ``fp32`` both are the plain operations (no autocast, ``loss.backward()``,
    ``optimizer.step()``), so a float32 run computes exactly what it computed before this
    class existed.
    """

    def __init__(self, name: str, device: torch.device) -> None:
        self.name = name
        self.device_type = device.type
        self.scaler = torch.amp.GradScaler(device.type, enabled=name == "fp16")

    def autocast(self) -> contextlib.AbstractContextManager:
        """Context of a training forward pass."""
        if self.name == "fp32":
            return contextlib.nullcontext()
        return torch.autocast(self.device_type, dtype=_DTYPES[self.name])

    def backward_step(self, loss: torch.Tensor, optimizer: torch.optim.Optimizer) -> None:
        """Back-propagate ``loss`` and step ``optimizer`` (loss-scaled in fp16; a step whose
        gradients overflowed is skipped and the scale lowered, as GradScaler does)."""
        self.scaler.scale(loss).backward()
        self.scaler.step(optimizer)
        self.scaler.update()

    def state_dict(self) -> dict[str, Any]:
        """The loss scaler's state (empty unless fp16): a checkpoint keeps it for an exact resume."""
        return self.scaler.state_dict()

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict`; a state saved in another precision (empty) leaves the scaler fresh."""
        if state and self.scaler.is_enabled():
            self.scaler.load_state_dict(state)

    def checkpoint_extra(self) -> dict[str, Any]:
        """What a checkpoint's ``extra`` keeps of the precision: its name and the loss scaler's state."""
        return {"precision": self.name, "grad_scaler": self.state_dict()}

    def restore(self, extra: dict[str, Any]) -> None:
        """Continue with the loss scale of a checkpoint's ``extra`` (:meth:`checkpoint_extra`)."""
        self.load_state_dict(extra.get("grad_scaler", {}))


def float32_outputs(outputs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """``outputs`` with every floating tensor in float32 (losses are computed in float32)."""
    return {key: value.float() if value.is_floating_point() else value for key, value in outputs.items()}
