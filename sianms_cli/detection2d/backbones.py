"""Backbones giving a stride-16 feature map of a camera image, for ROI features (docs/methods.md#roi-features).

- ``tiny``: a small seeded conv net (four 3x3 stride-2 convolutions, 64 channels), fast on a
  CPU; its features carry no learnt meaning but are deterministic, which is what tests and
  the synthetic default need.
- ``resnet50-c4``: ResNet-50 up to ``layer3`` (= res4, 1,024 channels, stride 16) with
  torchvision's module names, loaded from a local torchvision detection checkpoint
  (``backbone.body.*`` keys) or a plain torchvision ``resnet50``
  state dict; batch norms are frozen with eps = 0 as torchvision's COCO models. Input
  preprocessing as torchvision's ``GeneralizedRCNNTransform``: RGB in [0, 1],
  normalised with the ImageNet mean/std, resized by ``min(800 / short side, 1333 / long
  side)`` (bilinear), zero-padded to a multiple of 32.

A backbone maps an (H, W, 3) uint8 image to ``(features (1, C, h, w), (sx, sy))`` where
(sx, sy) multiply original-image pixel coordinates into the resized image; ROI Align then
uses ``spatial_scale = 1/16``. Nothing is downloaded: weights come only from ``--weights``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.io import check_regular_file

BACKBONES = ("tiny", "resnet50-c4")
STRIDE = 16
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
DETECTION_PREFIX = "backbone.body."


def _normalised(image: np.ndarray) -> torch.Tensor:
    """(H, W, 3) uint8 RGB -> (1, 3, H, W) float32 normalised with the ImageNet mean/std."""
    tensor = torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1).float().div_(255.0)
    mean = torch.tensor(IMAGENET_MEAN).view(3, 1, 1)
    std = torch.tensor(IMAGENET_STD).view(3, 1, 1)
    return ((tensor - mean) / std)[None]


def resize_and_pad(
    image: np.ndarray, min_size: int = 800, max_size: int = 1333, size_divisible: int = 32
) -> tuple[torch.Tensor, tuple[float, float]]:
    """torchvision's detection preprocessing of one image.

    Returns:
        ``(batch (1, 3, H', W'), (sx, sy))``: the normalised, resized, zero-padded image and
        the resize ratios new / original per axis (padding excluded).
    """
    tensor = _normalised(image)
    height, width = tensor.shape[-2:]
    scale = min(min_size / min(height, width), max_size / max(height, width))
    resized = F.interpolate(tensor, scale_factor=scale, mode="bilinear", align_corners=False,
                            recompute_scale_factor=True)
    new_h, new_w = resized.shape[-2:]
    pad_h = int(math.ceil(new_h / size_divisible) * size_divisible) - new_h
    pad_w = int(math.ceil(new_w / size_divisible) * size_divisible) - new_w
    padded = F.pad(resized, (0, pad_w, 0, pad_h))
    return padded, (new_w / width, new_h / height)


class TinyBackbone(nn.Module):
    """Four 3x3 stride-2 conv + ReLU layers (3 -> 16 -> 32 -> 64 -> 64), weights drawn from ``seed``."""

    channels = 64
    name = "tiny"

    def __init__(self, seed: int = 0) -> None:
        super().__init__()
        widths = (3, 16, 32, 64, 64)
        generator = torch.Generator().manual_seed(seed)
        layers: list[nn.Module] = []
        for cin, cout in zip(widths[:-1], widths[1:]):
            conv = nn.Conv2d(cin, cout, 3, stride=2, padding=1)
            with torch.no_grad():
                conv.weight.copy_(torch.randn(conv.weight.shape, generator=generator) * math.sqrt(2.0 / (9 * cin)))
                assert conv.bias is not None  # a Conv2d has one unless built with bias=False
                conv.bias.zero_()
            layers += [conv, nn.ReLU()]
        self.body = nn.Sequential(*layers)
        self.eval()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.body(x)

    @torch.no_grad()
    def features(self, image: np.ndarray) -> tuple[torch.Tensor, tuple[float, float]]:
        """Features of the image at its own resolution (no resize), normalised as ImageNet."""
        return self(_normalised(image)), (1.0, 1.0)


class FrozenBatchNorm2d(nn.Module):
    """Batch norm with fixed statistics, as torchvision's (buffers only; eps 0 for COCO weights)."""

    weight: torch.Tensor  # the buffers __init__ registers
    bias: torch.Tensor
    running_mean: torch.Tensor
    running_var: torch.Tensor

    def __init__(self, channels: int, eps: float = 0.0) -> None:
        super().__init__()
        self.eps = eps
        self.register_buffer("weight", torch.ones(channels))
        self.register_buffer("bias", torch.zeros(channels))
        self.register_buffer("running_mean", torch.zeros(channels))
        self.register_buffer("running_var", torch.ones(channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        scale = self.weight * (self.running_var + self.eps).rsqrt()
        shift = self.bias - self.running_mean * scale
        return x * scale.view(1, -1, 1, 1) + shift.view(1, -1, 1, 1)


class Bottleneck(nn.Module):
    """torchvision's ResNet v1.5 bottleneck (stride in the 3x3 conv)."""

    def __init__(self, inplanes: int, width: int, stride: int, downsample: bool) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(inplanes, width, 1, bias=False)
        self.bn1 = FrozenBatchNorm2d(width)
        self.conv2 = nn.Conv2d(width, width, 3, stride=stride, padding=1, bias=False)
        self.bn2 = FrozenBatchNorm2d(width)
        self.conv3 = nn.Conv2d(width, width * 4, 1, bias=False)
        self.bn3 = FrozenBatchNorm2d(width * 4)
        self.downsample = (
            nn.Sequential(nn.Conv2d(inplanes, width * 4, 1, stride=stride, bias=False), FrozenBatchNorm2d(width * 4))
            if downsample else None
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = F.relu(self.bn1(self.conv1(x)))
        out = F.relu(self.bn2(self.conv2(out)))
        return F.relu(self.bn3(self.conv3(out)) + identity)


def _layer(inplanes: int, width: int, blocks: int, stride: int) -> nn.Sequential:
    layers = [Bottleneck(inplanes, width, stride, downsample=True)]
    layers += [Bottleneck(width * 4, width, 1, downsample=False) for _ in range(blocks - 1)]
    return nn.Sequential(*layers)


class ResNet50C4(nn.Module):
    """ResNet-50 stem + layer1..layer3 (res4): 1,024 channels at stride 16, torchvision names."""

    channels = 1024
    name = "resnet50-c4"

    def __init__(self, min_size: int = 800, max_size: int = 1333) -> None:
        super().__init__()
        self.min_size, self.max_size = min_size, max_size
        self.conv1 = nn.Conv2d(3, 64, 7, stride=2, padding=3, bias=False)
        self.bn1 = FrozenBatchNorm2d(64)
        self.layer1 = _layer(64, 64, 3, 1)
        self.layer2 = _layer(256, 128, 4, 2)
        self.layer3 = _layer(512, 256, 6, 2)
        self.eval()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = F.max_pool2d(F.relu(self.bn1(self.conv1(x))), 3, stride=2, padding=1)
        return self.layer3(self.layer2(self.layer1(x)))

    @torch.no_grad()
    def features(self, image: np.ndarray) -> tuple[torch.Tensor, tuple[float, float]]:
        batch, ratios = resize_and_pad(image, self.min_size, self.max_size)
        return self(batch), ratios

    @classmethod
    def from_checkpoint(cls, path: str | Path, min_size: int = 800, max_size: int = 1333) -> ResNet50C4:
        """Load a torchvision detection checkpoint (``backbone.body.*``) or ``resnet50`` state dict.

        Only conv1, bn1 and layer1-3 are read (215 tensors); other keys are ignored.
        ``num_batches_tracked`` is optional. Missing keys or wrong shapes raise
        DataFormatError naming the file and the first offending key.
        """
        path = Path(path)
        if not path.exists():
            raise DataFormatError(path, "weights file not found")
        check_regular_file(path)  # a FIFO or a device would be read until memory runs out
        try:
            state = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as error:  # torch raises many types for bad files
            raise DataFormatError(path, f"not a torch checkpoint loadable with weights_only=True ({error})") from None
        if isinstance(state, dict) and isinstance(state.get("model"), dict):
            state = state["model"]
        if (not isinstance(state, dict) or not all(isinstance(k, str) for k in state)
                or not all(isinstance(v, torch.Tensor) for v in state.values())):
            raise DataFormatError(path, "expected a flat state dict (name -> tensor)")
        if any(key.startswith(DETECTION_PREFIX) for key in state):
            state = {key[len(DETECTION_PREFIX):]: value for key, value in state.items()
                     if key.startswith(DETECTION_PREFIX)}
        model = cls(min_size, max_size)
        expected = model.state_dict()
        missing = [key for key in expected if key not in state]
        if missing:
            raise DataFormatError(
                path, f"{len(missing)} backbone tensor(s) missing (expected torchvision ResNet-50 keys, "
                f"optionally prefixed '{DETECTION_PREFIX}')", field=missing[0])
        for key, value in expected.items():
            if tuple(state[key].shape) != tuple(value.shape):
                raise DataFormatError(path, f"shape {tuple(state[key].shape)}, expected {tuple(value.shape)}",
                                      field=key)
            if state[key].is_floating_point() and not torch.isfinite(state[key]).all():
                raise DataFormatError(path, "holds a NaN or an infinity: every ROI feature would be one",
                                      field=key)
        model.load_state_dict({key: state[key].float() for key in expected})
        return model


Backbone = TinyBackbone | ResNet50C4
"""A backbone :func:`build_backbone` makes."""


def build_backbone(name: str, weights: str | Path | None = None, seed: int = 0) -> Backbone:
    """The backbone ``name`` (one of BACKBONES); ``resnet50-c4`` needs ``weights``."""
    if name == "tiny":
        return TinyBackbone(seed)
    if name == "resnet50-c4":
        if weights is None:
            raise SianmsError("--backbone resnet50-c4 needs --weights PATH (a local torchvision "
                              "Faster/Mask R-CNN or resnet50 checkpoint; nothing is downloaded)")
        return ResNet50C4.from_checkpoint(weights)
    raise SianmsError(f"unknown backbone '{name}'; expected one of {', '.join(BACKBONES)}")
