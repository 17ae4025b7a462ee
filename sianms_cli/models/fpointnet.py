"""Frustum PointNets v1 (Qi et al., CVPR 2018), as the released code builds it
(docs/methods.md#three-stages).

Three stages on a batch of frustums, each frustum ``(N, C)`` points in its frustum frame
(x right, y down, z along the frustum's centre ray; xyz + intensity, C = 4):

1. 3-D instance segmentation PointNet: per-point MLP 64-64-64-128-1024, max-pool, concat the
   one-hot class, per-point head 512-256-128-128, dropout 0.5, 2 logits (clutter, object).
2. Masking: the points predicted as object, translated by their mean, ``num_object_points``
   (512) of them gathered; a T-Net (128-128-256, max-pool, one-hot, FC 256-128-3) regresses
   the residual from that mean to the box centre (``stage1_center``).
3. Amodal box PointNet on the masked points relative to ``stage1_center`` (128-128-256-512,
   max-pool, one-hot, FC 512-256) -> centre residual, NH heading-bin scores and normalised
   residuals, NS size-cluster scores and normalised residuals
   (docs/methods.md#heading-bins-and-size-clusters).

Sizes are (l, w, h) as the original: the conversion from nuScenes' (w, l, h) happens once, in
:mod:`sianms_cli.data.frustum_dataset`. The per-point layers and max pools are
:mod:`sianms_cli.models.point_layers`.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from sianms_cli.models.global_batch import BatchShare, batch_norm, dropout, uniform
from sianms_cli.models.point_layers import PointLinear, PooledPointLinear

NUM_HEADING_BINS = 12
NUM_OBJECT_POINTS = 512


def _mlp(widths: list[int], pooled: bool = False) -> nn.Sequential:
    """PointLinear layers through consecutive ``widths``; ``pooled``: the last one max-pools over
    the points (:class:`~sianms_cli.models.point_layers.PooledPointLinear`)."""
    pairs = list(zip(widths[:-1], widths[1:]))
    return nn.Sequential(*[PooledPointLinear(a, b) if pooled and i == len(pairs) - 1 else PointLinear(a, b)
                           for i, (a, b) in enumerate(pairs)])


class FPointNetV1(nn.Module):
    """Frustum PointNets v1.

    Args:
        mean_sizes: (NS, 3) mean (l, w, h) of each size cluster, metres; one cluster per class.
        in_channels: point channels (4: xyz + intensity; 3 without intensity).
        num_heading_bins: NH (12 as the original).
        num_object_points: points gathered after masking (512 as the original).
    """

    mean_sizes: torch.Tensor  # the buffer __init__ registers

    def __init__(self, mean_sizes: torch.Tensor, in_channels: int = 4, num_heading_bins: int = NUM_HEADING_BINS,
                 num_object_points: int = NUM_OBJECT_POINTS) -> None:
        super().__init__()
        mean_sizes = torch.as_tensor(mean_sizes, dtype=torch.float32).reshape(-1, 3)
        self.register_buffer("mean_sizes", mean_sizes)
        self.num_classes = len(mean_sizes)
        self.num_heading_bins = num_heading_bins
        self.num_object_points = num_object_points
        k, nh, ns = self.num_classes, num_heading_bins, self.num_classes
        self.seg_point = _mlp([in_channels, 64, 64, 64])
        self.seg_global = _mlp([64, 128, 1024], pooled=True)
        self.seg_head = nn.Sequential(_mlp([64 + 1024 + k, 512, 256, 128, 128]), nn.Dropout(0.5), nn.Linear(128, 2))
        self.tnet_point = _mlp([3, 128, 128, 256], pooled=True)
        self.tnet_head = nn.Sequential(_mlp([256 + k, 256, 128]), nn.Linear(128, 3))
        self.box_point = _mlp([3, 128, 128, 256, 512], pooled=True)
        self.box_head = nn.Sequential(_mlp([512 + k, 512, 256]), nn.Linear(256, 3 + 2 * nh + 4 * ns))
        for module in self.modules():
            if isinstance(module, nn.Linear):  # the original's Xavier initialisation
                nn.init.xavier_uniform_(module.weight)
                nn.init.zeros_(module.bias)

    def set_bn_momentum(self, momentum: float) -> None:
        """PyTorch momentum (weight of the new batch) of every batch norm: the BN-decay schedule."""
        for module in self.modules():
            if isinstance(module, nn.BatchNorm1d):
                module.momentum = momentum

    def forward(self, points: torch.Tensor, one_hot: torch.Tensor, generator: torch.Generator | None = None,
                share: BatchShare | None = None) -> dict[str, torch.Tensor]:
        """Segment, mask, regress the box.

        Args:
            points: (B, N, C) frustum-frame points; xyz first.
            one_hot: (B, K) class vector.
            generator: random source of the masked-point gathering (None: torch's global one).
            share: the rows of a global batch these frustums are, on one rank of a distributed
                training: random draws are made for the global batch (dropout's from torch's
                global generator) and these rows kept. None: the frustums are the batch.

        Returns:
            dict of ``seg_logits`` (B, N, 2), ``mask`` (B, N) bool, ``mask_mean`` (B, 3),
            ``center_delta`` (B, 3), ``stage1_center`` (B, 3), ``center`` (B, 3),
            ``heading_scores`` (B, NH), ``heading_residuals_normalized`` and
            ``heading_residuals`` (B, NH) (radians = normalised x pi/NH),
            ``size_scores`` (B, NS), ``size_residuals_normalized`` and ``size_residuals``
            (B, NS, 3) (metres = normalised x mean size).
        """
        one_hot = one_hot.to(points.dtype)
        point_feature = self.seg_point(points)
        global_feature = torch.cat([self.seg_global(point_feature), one_hot], dim=1)
        point_head, seg_dropout, seg_logits_layer = self._seg_head_parts()
        seg_feature = point_head[1:](self._seg_head_first_layer(point_feature, global_feature))
        seg_logits = seg_logits_layer(dropout(seg_feature, seg_dropout.p, share, self.training))

        mask = seg_logits[..., 1] > seg_logits[..., 0]
        xyz = points[..., :3]
        counts = mask.sum(dim=1, keepdim=True)
        mask_mean = (xyz * mask[..., None]).sum(dim=1) / counts.clamp(min=1)
        object_xyz = gather_object_points(xyz - mask_mean[:, None, :], mask, self.num_object_points, generator, share)

        center_delta = self.tnet_head(torch.cat([self.tnet_point(object_xyz), one_hot], dim=1))
        stage1_center = mask_mean + center_delta
        box_input = object_xyz - center_delta[:, None, :]
        box = self.box_head(torch.cat([self.box_point(box_input), one_hot], dim=1))
        return {"seg_logits": seg_logits, "mask": mask, "mask_mean": mask_mean, "center_delta": center_delta,
                "stage1_center": stage1_center, **self.parse_box_output(box, stage1_center)}

    def _seg_head_first_layer(self, point_feature: torch.Tensor, global_feature: torch.Tensor) -> torch.Tensor:
        """The segmentation head's first layer on [point feature, global feature tiled to every point].

        The original concatenates and applies one linear map per point; the global part of that
        map is the same for every point of a frustum, so it is applied once per frustum and
        broadcast: the same function, with 1,024 x 512 fewer multiply-adds per point (the
        largest layer of the network).
        """
        layer = self._seg_head_parts()[0][0]
        assert isinstance(layer, PointLinear)  # _mlp builds of them only
        local = point_feature.shape[-1]
        weight = layer.linear.weight
        per_point = point_feature @ weight[:, :local].T
        if layer.leaves_out_bias():
            y = per_point + (global_feature @ weight[:, local:].T)[:, None, :]
            normalised = layer.normalise_in_training(y.reshape(-1, y.shape[-1]))
        else:
            y = per_point + torch.addmm(layer.linear.bias, global_feature, weight[:, local:].T)[:, None, :]
            normalised = batch_norm(layer.norm, y.reshape(-1, y.shape[-1]))
        return torch.relu(normalised).reshape(*y.shape)

    def _seg_head_parts(self) -> tuple[nn.Sequential, nn.Dropout, nn.Linear]:
        """The segmentation head's MLP, dropout and logits layer, as __init__ builds them."""
        mlp, seg_dropout, logits = self.seg_head
        assert isinstance(mlp, nn.Sequential) and isinstance(seg_dropout, nn.Dropout) and isinstance(logits, nn.Linear)
        return mlp, seg_dropout, logits

    def parse_box_output(self, box: torch.Tensor, stage1_center: torch.Tensor) -> dict[str, torch.Tensor]:
        """Split the box net's ``3 + 2 NH + 4 NS`` outputs in the original's order
        (docs/methods.md#heading-bins-and-size-clusters)."""
        nh, ns = self.num_heading_bins, self.num_classes
        heading_normalized = box[:, 3 + nh:3 + 2 * nh]
        size_normalized = box[:, 3 + 2 * nh + ns:].reshape(-1, ns, 3)
        return {
            "center": stage1_center + box[:, :3],
            "heading_scores": box[:, 3:3 + nh],
            "heading_residuals_normalized": heading_normalized,
            "heading_residuals": heading_normalized * (math.pi / nh),
            "size_scores": box[:, 3 + 2 * nh:3 + 2 * nh + ns],
            "size_residuals_normalized": size_normalized,
            "size_residuals": size_normalized * self.mean_sizes[None],
        }


def gather_object_points(xyz: torch.Tensor, mask: torch.Tensor, count: int,
                         generator: torch.Generator | None = None, share: BatchShare | None = None) -> torch.Tensor:
    """(B, count, 3): ``count`` of each frustum's masked points, as the original's masking.

    More masked points than ``count``: a random subset without replacement; fewer: all of
    them plus random repeats; none: ``count`` copies of point 0 (docs/methods.md#three-stages). Done for the
    whole batch at once: sorting by ``mask + uniform`` puts each frustum's masked points first,
    in random order. The original also shuffles the result; the max-pools that follow make
    the order irrelevant, so it is not shuffled here. ``share``: as :meth:`FPointNetV1.forward`'s.
    """
    batch, points = mask.shape
    keys = mask.to(xyz.dtype) + uniform(batch, points, share, generator=generator, device=xyz.device, dtype=xyz.dtype)
    order = keys.argsort(dim=1, descending=True)
    masked = mask.sum(dim=1, keepdim=True)
    slot = torch.arange(count, device=xyz.device)[None, :].expand(batch, -1)
    repeat = (uniform(batch, count, share, generator=generator, device=xyz.device) * masked).long()
    slot = torch.where(slot < masked, slot, repeat)
    index = torch.gather(order, 1, slot.clamp(max=points - 1))
    index = torch.where(masked > 0, index, torch.zeros_like(index))
    return torch.gather(xyz, 1, index[..., None].expand(-1, -1, 3))
