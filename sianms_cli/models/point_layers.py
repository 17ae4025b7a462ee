"""PointNet's per-point layers: a shared linear map -> batch norm -> ReLU on every point, and the
max pool over the points that ends a PointNet (docs/methods.md#three-stages).

Every per-point "1x1 conv" of the original is an ``nn.Linear`` on the last axis (the same map as
``Conv1d(k=1)``, faster on CPUs), followed by batch norm (epsilon 1e-3, TF's) and ReLU. The last
layer before a max pool is :class:`PooledPointLinear`, which pools as well; the ReLU follows
the pool there (:func:`pooled_relu`).
"""

from __future__ import annotations

import torch
from torch import nn

from sianms_cli.models.global_batch import batch_norm, synchronised

BN_EPSILON = 1e-3  # TF batch_norm's default, which the original trained with
POOL_BLOCK = 16  # points per block of a max pool: block maxima are a fast reduction, then one block is searched
# A pooled layer widening its input this many times or more trains through its input's covariance
# (PooledPointLinear): bench/train_step_parts.py measured 128 -> 1,024 1.8-2.8x faster so, and
# 128 -> 256 and 256 -> 512 0.7x (docs/performance.md#training-sianms-train).
COVARIANCE_MIN_WIDENING = 4


class PointLinear(nn.Module):
    """Shared per-point linear -> batch norm -> ReLU on ``(B, N, C)`` (or FC on ``(B, C)``); the
    batch norm is synchronised over the ranks of a distributed training (:mod:`~sianms_cli.models.global_batch`).
    ``relu=False`` leaves the ReLU out.

    In training, batch norm subtracts the batch's mean, which cancels the linear map's bias in the
    outputs and their gradients: the bias is not added to every row only to be subtracted, and
    only the running mean takes it (:meth:`normalise_in_training`); its gradient is None. Under
    a process group of several ranks it is added as usual, since DistributedDataParallel
    expects a gradient for every parameter.
    """

    def __init__(self, inputs: int, outputs: int, relu: bool = True) -> None:
        super().__init__()
        self.linear = nn.Linear(inputs, outputs)
        self.norm = nn.BatchNorm1d(outputs, eps=BN_EPSILON)
        self.relu = relu

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        shape = x.shape
        flat = x.reshape(-1, shape[-1])
        if self.leaves_out_bias():
            y = self.normalise_in_training(nn.functional.linear(flat, self.linear.weight))
        else:
            y = batch_norm(self.norm, self.linear(flat))
        return (torch.relu(y) if self.relu else y).reshape(*shape[:-1], y.shape[-1])

    def leaves_out_bias(self) -> bool:
        """Whether a forward pass now leaves out the linear map's bias: in training, in one process."""
        return self.norm.training and not synchronised(self.norm)

    def normalise_in_training(self, unbiased: torch.Tensor) -> torch.Tensor:
        """Training batch norm of (M, C') rows ``unbiased + bias``, given the linear map's outputs
        without its bias: the outputs do not depend on it, the running mean does."""
        y = batch_norm(self.norm, unbiased)
        _track_running_statistics(self.norm, self.linear.bias)
        return y


class PooledPointLinear(PointLinear):
    """The last per-point layer of a PointNet and its max pool: ``(B, N, C)`` -> ``(B, C')``, the
    maximum over the points of ReLU(batch norm(linear)), as the original.

    In a training step of one process, a layer that widens its input at least
    ``COVARIANCE_MIN_WIDENING`` times computes the same values and gradients from the input's
    C x C covariance and the B x C' maxima (:class:`_CovariancePool`): the B x N x C' normalised
    outputs are never formed, and the backward pass has no B·N x C' products. Elsewhere
    (evaluation, a narrower layer, batch norm synchronised over ranks) it is the per-point layer
    followed by :func:`pooled_relu`.
    """

    def __init__(self, inputs: int, outputs: int) -> None:
        super().__init__(inputs, outputs, relu=False)
        self.by_covariance = outputs >= COVARIANCE_MIN_WIDENING * inputs

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        norm = self.norm
        if not (self.by_covariance and self.leaves_out_bias() and x.shape[0] * x.shape[1] > 1):
            return pooled_relu(super().forward(x))
        dtype = torch.get_autocast_dtype(x.device.type) if torch.is_autocast_enabled(x.device.type) else x.dtype
        pooled, mean, variance = _CovariancePool.apply(x, self.linear.weight, norm.weight, norm.bias, norm.eps, dtype)
        _track_running_statistics(norm, self.linear.bias, (mean, variance))
        return torch.relu(pooled)


def _track_running_statistics(norm: nn.BatchNorm1d, bias: torch.Tensor,
                              batch: tuple[torch.Tensor, torch.Tensor] | None = None) -> None:
    """``norm``'s running statistics, as ``nn.BatchNorm1d`` keeps them for a linear map's outputs,
    after a training batch of those outputs without the map's ``bias``. ``batch``: that batch's
    (mean, unbiased variance), where ``norm`` has not counted and tracked it itself."""
    running_mean, running_var, batches = norm.running_mean, norm.running_var, norm.num_batches_tracked
    assert running_mean is not None and running_var is not None and batches is not None  # the models track them
    with torch.no_grad():
        if batch is not None:
            batches.add_(1)
        factor = norm.momentum if norm.momentum is not None else 1 / float(batches)
        if batch is not None:
            running_mean.lerp_(batch[0].to(running_mean.dtype), factor)
            running_var.lerp_(batch[1].to(running_var.dtype), factor)
        # Batch norm's backward node keeps the running mean (read in evaluation mode only): ``.data``
        # keeps this update off the version count that node checks.
        running_mean.data.add_(bias.to(running_mean.dtype), alpha=factor)


class _CovariancePool(torch.autograd.Function):
    """Max over the points of batch norm (training statistics) of ``x W^T``, from the input's
    covariance: (B, N, C) -> (B, C'), with the batch's mean and unbiased variance of ``x W^T``
    (a bias would cancel: :class:`PointLinear`).

    Batch norm is affine per channel, so its maximum over the points is the affine map of the
    maximum of ``x W^T``, or of its minimum where the scale gamma is negative: the outputs of
    channel k are multiplied by sign(gamma_k) (``signed``) and maximised. The statistics of a
    linear map follow from the input's: mean ``W mean(x)`` and variance ``w_k^T Sigma w_k``,
    Sigma the C x C covariance of the input rows. The gradient reaches the maximising row of each
    (frustum, channel) and, through the statistics, every row by ``Sigma``'s gradient: a C x C
    matrix. The input's covariance and all statistics are in float32 (float64 for a float64
    model); the one B·N x C' product, the forward pass's, runs in ``dtype`` (autocast's).
    """

    @staticmethod
    def forward(ctx, x: torch.Tensor, weight: torch.Tensor, gamma: torch.Tensor, beta: torch.Tensor, eps: float,
                dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        with torch.autocast(x.device.type, enabled=False):
            batch, points, channels = x.shape
            rows = batch * points
            flat = x.reshape(rows, channels)
            stats = torch.promote_types(weight.dtype, torch.float32)
            sign = torch.where(gamma < 0, -1.0, 1.0).to(stats)
            signed = weight.to(stats) * sign[:, None]
            products = (flat.to(dtype) @ signed.to(dtype).T).view(batch, points, -1)
            maxima, where = max_over_points(products, POOL_BLOCK)
            del products
            inputs = flat.to(stats)
            input_mean = inputs.mean(dim=0)
            centred = inputs - input_mean
            signed_covariance = signed @ (centred.T @ centred / rows)  # W Sigma, the signed W
            mean = signed @ input_mean
            variance = (signed_covariance * signed).sum(dim=1)
            inverse_std = torch.rsqrt(variance + eps)
            normalised = (maxima.to(stats) - mean) * inverse_std
            ctx.save_for_backward(x, where, signed, sign, signed_covariance, input_mean, inverse_std, normalised, gamma)
            ctx.dtype = dtype
            statistics = sign * mean, variance * (rows / (rows - 1))
            ctx.mark_non_differentiable(*statistics)
            return normalised * gamma.abs().to(stats) + beta.to(stats), *statistics

    @staticmethod
    def backward(ctx, gradient: torch.Tensor, *_: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        x, where, signed, sign, signed_covariance, input_mean, inverse_std, normalised, gamma = ctx.saved_tensors
        with torch.autocast(x.device.type, enabled=False):
            batch, points, channels = x.shape
            rows = batch * points
            gradient = gradient.to(inverse_std.dtype)
            gradient_beta = gradient.sum(dim=0)
            gradient_gamma = sign * (gradient * normalised).sum(dim=0)
            at_maxima = gradient * (gamma.abs() * inverse_std)
            gradient_mean = -at_maxima.sum(dim=0)
            gradient_variance = -0.5 * inverse_std * (at_maxima * normalised).sum(dim=0)
            # The maxima's own rows: per channel, the weights' gradient sums the rows its maxima came
            # from (channel-major bags); per row, the input's sums the weights of the channels maximal
            # there (row-major bags, most of them empty).
            maximising = (torch.arange(batch, device=where.device)[:, None] * points + where).reshape(-1)
            flat = x.reshape(rows, channels)
            by_channel = maximising.view(batch, -1).T.reshape(-1)
            channel_starts = torch.arange(0, by_channel.numel(), batch, device=where.device)
            gradient_signed = nn.functional.embedding_bag(by_channel, flat, channel_starts, mode="sum",
                                                          per_sample_weights=at_maxima.T.reshape(-1).to(x.dtype))
            order = torch.sort(maximising, stable=True).indices
            per_row = torch.bincount(maximising, minlength=rows)
            channel_of = torch.arange(signed.shape[0], device=where.device).repeat(batch)
            gradient_x = nn.functional.embedding_bag(channel_of[order], signed, per_row.cumsum(0) - per_row,
                                                     mode="sum", per_sample_weights=at_maxima.reshape(-1)[order])
            # Through the statistics: the mean moves every row alike, the covariance by a C x C map.
            gradient_signed = gradient_signed.to(signed.dtype) + gradient_mean[:, None] * input_mean
            gradient_signed += (2 * gradient_variance)[:, None] * signed_covariance
            gradient_x += (gradient_mean @ signed) / rows
            gradient_covariance = (signed.T * (2 / rows * gradient_variance)) @ signed
            dtype = ctx.dtype
            gradient_x += ((flat.to(dtype) - input_mean.to(dtype)) @ gradient_covariance.to(dtype)).to(signed.dtype)
            return (gradient_x.view(x.shape).to(x.dtype), (gradient_signed * sign[:, None]).to(gamma.dtype),
                    gradient_gamma.to(gamma.dtype), gradient_beta.to(gamma.dtype), None, None)


def pooled_relu(x: torch.Tensor) -> torch.Tensor:
    """(B, N, C) batch-norm outputs -> (B, C): ReLU, then the maximum over the points, with the
    gradient routed to one point per channel (the original's max pool of ReLU outputs).

    ReLU is monotone, so it is applied to the B x C maxima instead of the B x N x C outputs, in
    both passes. TF's MaxPool, which the original trained with, passes the gradient to one
    maximum; ``amax`` shares it among tied maxima and, to find them, compares every point with
    the maximum in its backward pass, and ``max(dim=1)`` finds indices slowly across the point
    axis and scatters slowly back: either cost about a third of a bfloat16 training step at 256
    points (docs/performance.md). The ways differ only at ties above zero, which here are exact
    duplicates among the gathered object points (whose weight gradients sum to the same) or
    coincidences of rounding.
    """
    return torch.relu(_MaxPool.apply(x))


class _MaxPool(torch.autograd.Function):
    """:func:`pooled_relu`'s maximum: found block-wise, the gradient written to its flat positions."""

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:
        values, indices = max_over_points(x, POOL_BLOCK)
        ctx.save_for_backward(indices)
        ctx.shape = x.shape
        return values

    @staticmethod
    def backward(ctx, gradient: torch.Tensor) -> torch.Tensor:
        (indices,) = ctx.saved_tensors
        batch, points, channels = ctx.shape
        rows = torch.arange(batch, device=indices.device)[:, None] * (points * channels)
        flat = rows + indices * channels + torch.arange(channels, device=indices.device)
        result = gradient.new_zeros(batch * points * channels)
        result[flat.reshape(-1)] = gradient.reshape(-1)
        return result.reshape(batch, points, channels)


def max_over_points(x: torch.Tensor, block: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(values, indices) of the maximum over dim 1 of (B, N, C): per block of ``block`` points, then
    within the block holding it; ``x.max(dim=1)`` where N is not a multiple of ``block``."""
    points = x.shape[1]
    if points % block:
        values, indices = x.max(dim=1)
        return values, indices
    values, winner = x.unflatten(1, (points // block, block)).amax(dim=2).max(dim=1)
    rows = winner[:, None, :] * block + torch.arange(block, device=x.device)[None, :, None]
    within = x.gather(1, rows).max(dim=1).indices
    return values, winner * block + within
