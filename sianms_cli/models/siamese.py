"""The siamese embedding network of the paper's Fig. 4, on cached ROI feature maps.

Each branch is the same encoder (shared weights, so one module embeds both): two groups of
3×3 convolution + ReLU + 2×2 max pooling, then fully connected layers to a d-dimensional
embedding (d = 100 in the paper). The paper gives neither the widths nor the ROI size, so
widths are config fields, and pooling uses ``ceil_mode`` so any ROI size works (7 → 4 → 2,
14 → 7 → 4, 1 → 1 → 1). The embedding is not normalised: eq. (6) needs distances above β = 3.

Input standardisation (optional): backbone channels differ in scale (the ``tiny``
backbone's by 30×), so the encoder first maps every channel c to (x − mean_c) / std_c.
The per-channel statistics
are buffers (``input_mean``, ``input_std``, shape (C,)), set once from the training cache
(:meth:`SiameseEncoder.set_input_statistics`) and saved in the state dict: a checkpoint
carries them and inference needs nothing but the checkpoint. They default to 0 and 1 (the
identity: the paper's raw features) until set.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

MIN_STD = 1e-6  # a constant channel is divided by this, not by zero


class SiameseEncoder(nn.Module):
    """(N, C, PH, PW) ROI features -> (N, d) embeddings (float32, unnormalised).

    Args:
        feature_shape: (C, PH, PW) of the cache's ROI features.
        dim: embedding size d.
        conv_channels: output channels of the two convolution groups.
        hidden: widths of the hidden fully connected layers (ReLU after each).
    """

    input_mean: torch.Tensor  # the buffers __init__ registers
    input_std: torch.Tensor

    def __init__(self, feature_shape: tuple[int, int, int], dim: int = 100,
                 conv_channels: tuple[int, int] = (128, 128), hidden: tuple[int, ...] = (256,)) -> None:
        super().__init__()
        channels, height, width = (int(v) for v in feature_shape)
        self.register_buffer("input_mean", torch.zeros(channels))
        self.register_buffer("input_std", torch.ones(channels))
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

    def set_input_statistics(self, mean: np.ndarray | torch.Tensor, std: np.ndarray | torch.Tensor) -> None:
        """Set the per-channel input statistics, (C,) each; std is floored at ``MIN_STD``."""
        mean = torch.as_tensor(np.asarray(mean, dtype=np.float32))
        std = torch.as_tensor(np.asarray(std, dtype=np.float32)).clamp(min=MIN_STD)
        expected = (self.feature_shape[0],)
        if tuple(mean.shape) != expected or tuple(std.shape) != expected:
            raise ValueError(f"input statistics must have shape {expected}, "
                             f"got {tuple(mean.shape)}, {tuple(std.shape)}")
        self.input_mean.copy_(mean)
        self.input_std.copy_(std)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        standardised = (features - self.input_mean[:, None, None]) / self.input_std[:, None, None]
        return self.head(self.features(standardised).flatten(1))


def parameter_count(module: nn.Module) -> int:
    """Trainable parameters (the sweep's table reports it per d)."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)
