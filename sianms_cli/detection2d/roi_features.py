"""ROI features of the 2D boxes of one image: backbone stride-16 map, then ROI Align.

The paper's siamese network embeds each detection from the ROI-pooled features of the
detector's backbone (paper §III-A). The features are stored as little-endian float16, the cache's
format (``sianms.roi_feature_dtype = "<f2"``), which halves the cache at no loss the
embedding network can notice.
"""

from __future__ import annotations

import numpy as np
import torch

from sianms_cli.detection2d.backbones import STRIDE, Backbone
from sianms_cli.detection2d.roi_align import roi_align

FEATURE_DTYPE = "<f2"


def roi_feature_shape(backbone: Backbone, roi_size: int) -> tuple[int, int, int]:
    """(C, PH, PW) of one box's features."""
    return (int(backbone.channels), roi_size, roi_size)


def roi_features(backbone: Backbone, image: np.ndarray, boxes: np.ndarray, roi_size: int,
                 sampling_ratio: int) -> np.ndarray:
    """ROI-Align features of boxes in one image.

    Args:
        backbone: a backbone of :mod:`sianms_cli.detection2d.backbones` (``features(image)``
            gives a stride-16 map and the resize ratios of the image it ran on).
        image: (H, W, 3) uint8 RGB.
        boxes: (K, 4) [x1, y1, x2, y2] pixels of the original image.
        roi_size: output bins per side (PH = PW).
        sampling_ratio: samples per bin side; <= 0 for the adaptive ``ceil(roi / bins)``.

    Returns:
        (K, C, roi_size, roi_size) little-endian float16, C-contiguous.
    """
    features, (sx, sy) = backbone.features(image)
    scaled = torch.as_tensor(np.asarray(boxes, dtype=np.float64).reshape(-1, 4) * np.array([sx, sy, sx, sy]),
                             dtype=torch.float64)
    pooled = roi_align(features, [scaled], roi_size, 1.0 / STRIDE, sampling_ratio, aligned=True)
    return np.ascontiguousarray(pooled.to(torch.float16).numpy().astype(FEATURE_DTYPE))
