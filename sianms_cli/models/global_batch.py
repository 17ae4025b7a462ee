"""One process's share of a global batch, computed as one process computes the whole batch.

Under DistributedDataParallel each of K processes (ranks) holds rows of every global batch
and DDP averages the gradients. That equals one process on the whole batch only for layers
that see each example alone. Two things in Frustum PointNets see the whole batch:

- random draws (dropout masks, the masked-point gathering) are made in one call for the
  batch; here every rank draws for the whole global batch from the same generator state
  and keeps its rows, so the draws do not depend on how the batch is split;
- batch norm normalises with the batch's statistics; here, in training under a process
  group, the per-channel sums are all-reduced (differentiably: the backward pass
  all-reduces too) so every rank normalises with the global batch's mean and variance.
  torch's ``SyncBatchNorm`` does this on GPUs only; this runs on the gloo (CPU) and NCCL
  backends alike.

In one process (no share, or no process group) every function here is the plain operation:
the same draws from the same generators, ``nn.BatchNorm1d`` itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.distributed as dist
from torch import nn


@dataclass(frozen=True)
class BatchShare:
    """Rows [start, stop) of a global batch of ``size`` rows, held by one rank."""

    start: int
    stop: int
    size: int

    @classmethod
    def of_counts(cls, counts: list[int], rank: int) -> BatchShare:
        """Rank ``rank``'s rows when the ranks hold ``counts`` rows of the global batch, in rank order."""
        return cls(sum(counts[:rank]), sum(counts[:rank + 1]), sum(counts))

    def __len__(self) -> int:
        return self.stop - self.start

    def loss_weight(self, world: int) -> float:
        """Factor on a mean over this share's rows so that DDP's average of the ranks' gradients
        is the gradient of the mean over the global batch (1 for the whole batch in one process)."""
        return world * len(self) / self.size


def uniform(rows: int, columns: int, share: BatchShare | None, *, generator: torch.Generator | None = None,
            device: torch.device | None = None, dtype: torch.dtype | None = None) -> torch.Tensor:
    """(rows, columns) uniform [0, 1) draws: the share's rows of one draw for the global batch."""
    if share is None:
        return torch.rand(rows, columns, generator=generator, device=device, dtype=dtype)
    return torch.rand(share.size, columns, generator=generator, device=device, dtype=dtype)[share.start:share.stop]


def dropout(x: torch.Tensor, p: float, share: BatchShare | None, training: bool) -> torch.Tensor:
    """Inverted dropout: ``x`` times a Bernoulli(1 - p) mask of its shape (:func:`keep_mask`, from
    torch's global generator), scaled by 1 / (1 - p). The mask of a share is its rows of the
    global batch's mask. (``torch.nn.functional.dropout``'s own Bernoulli draws cost 6 % of a
    bfloat16 training step: docs/performance.md#training-sianms-train.)"""
    if not training or p == 0:
        return x
    keep = keep_mask(x.shape if share is None else (share.size, *x.shape[1:]), 1 - p, x.device)
    if share is not None:
        keep = keep[share.start:share.stop]
    return x * keep.to(x.dtype).mul_(1 / (1 - p))


BITS_PER_DRAW = 31  # an int32 draw of torch's generator is uniform on [0, 2^31): 31 fair bits


def keep_mask(shape: tuple[int, ...] | torch.Size, keep: float, device: torch.device) -> torch.Tensor:
    """Bernoulli(``keep``) booleans of ``shape`` from torch's global generator: at ``keep`` = 0.5
    one random bit each, 31 to a draw; else one uniform float each, kept below ``keep``."""
    if keep != 0.5:
        return torch.rand(shape, device=device) < keep
    count = math.prod(shape)
    draws = torch.empty(-(-count // BITS_PER_DRAW), dtype=torch.int32, device=device).random_()
    bits = draws[:, None] >> torch.arange(BITS_PER_DRAW, dtype=torch.int32, device=device)
    return (bits & 1).reshape(-1)[:count].reshape(shape).bool()


def synchronised(norm: nn.BatchNorm1d) -> bool:
    """Whether ``norm`` normalises with every rank's rows: in training under a process group of several ranks."""
    return norm.training and dist.is_available() and dist.is_initialized() and dist.get_world_size() > 1


def batch_norm(norm: nn.BatchNorm1d, x: torch.Tensor) -> torch.Tensor:
    """``norm`` on (M, C) rows; in training under a process group of several ranks, with the
    statistics of every rank's rows together (module docstring)."""
    if not synchronised(norm):
        return norm(x)
    x = x.to(torch.promote_types(x.dtype, torch.float32))  # under autocast, statistics in float32, not bfloat16
    count = torch.full((1,), x.shape[0], dtype=x.dtype, device=x.device)
    sums = _AllReduceSum.apply(torch.cat([x.sum(dim=0), count]))
    total = sums[-1]
    mean = sums[:-1] / total
    centered = x - mean
    variance = _AllReduceSum.apply(centered.square().sum(dim=0)) / total
    momentum, running_mean, running_var, batches = (norm.momentum, norm.running_mean, norm.running_var,
                                                    norm.num_batches_tracked)
    # The models' norms keep running statistics with a momentum (torch's defaults, which they keep)
    assert momentum is not None and running_mean is not None and running_var is not None and batches is not None
    with torch.no_grad():
        running_mean.mul_(1 - momentum).add_(mean.detach(), alpha=momentum)
        running_var.mul_(1 - momentum).add_(variance.detach() * (total / (total - 1)), alpha=momentum)
        batches.add_(1)
    return centered * torch.rsqrt(variance + norm.eps) * norm.weight + norm.bias


class _AllReduceSum(torch.autograd.Function):
    """The sum of a tensor over every rank; its gradient, the sum of the ranks' gradients."""

    @staticmethod
    def forward(ctx, tensor: torch.Tensor) -> torch.Tensor:
        total = tensor.clone()
        dist.all_reduce(total)
        return total

    @staticmethod
    def backward(ctx, gradient: torch.Tensor) -> torch.Tensor:
        total = gradient.clone()
        dist.all_reduce(total)
        return total
