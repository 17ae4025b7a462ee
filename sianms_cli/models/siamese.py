"""The siamese embedding network of the paper's Fig. 4, on cached ROI feature maps.

Each branch is the same encoder (shared weights, so one module embeds both): two groups of
3×3 convolution + ReLU + 2×2 max pooling, then fully connected layers to a d-dimensional
embedding (d = 100 in the paper). The paper gives neither the widths nor the ROI size, so
widths are config fields, and pooling uses ``ceil_mode`` so any ROI size works (7 → 4 → 2,
14 → 7 → 4, 1 → 1 → 1). The embedding is not normalised: eq. (6) needs distances above β = 3.
"""

from __future__ import annotations

import torch
from torch import nn


class SiameseEncoder(nn.Module):
    """(N, C, PH, PW) ROI features -> (N, d) embeddings.

    Args:
        feature_shape: (C, PH, PW) of the cache's ROI features.
        dim: embedding size d.
        conv_channels: output channels of the two convolution groups.
        hidden: widths of the hidden fully connected layers (ReLU after each).
    """

    def __init__(self, feature_shape: tuple[int, int, int], dim: int = 100,
                 conv_channels: tuple[int, int] = (128, 128), hidden: tuple[int, ...] = (256,)) -> None:
        super().__init__()
        channels, height, width = (int(v) for v in feature_shape)
        layers: list[nn.Module] = []
        for out_channels in conv_channels:
            layers += [nn.Conv2d(channels, out_channels, 3, padding=1), nn.ReLU(inplace=True),
                       nn.MaxPool2d(2, ceil_mode=True)]
            channels = out_channels
            height, width = -(-height // 2), -(-width // 2)
        self.features = nn.Sequential(*layers)
        widths = [channels * height * width, *hidden]
        fc: list[nn.Module] = []
        for size_in, size_out in zip(widths[:-1], widths[1:]):
            fc += [nn.Linear(size_in, size_out), nn.ReLU(inplace=True)]
        fc.append(nn.Linear(widths[-1], dim))
        self.head = nn.Sequential(*fc)
        self.feature_shape = (int(feature_shape[0]), int(feature_shape[1]), int(feature_shape[2]))
        self.dim = dim

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return self.head(self.features(features).flatten(1))


def parameter_count(module: nn.Module) -> int:
    """Trainable parameters (the sweep's table reports it per d)."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)
