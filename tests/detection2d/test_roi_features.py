import numpy as np
import torch

from sianms_cli.detection2d.backbones import TinyBackbone
from sianms_cli.detection2d.roi_align import roi_align_reference
from sianms_cli.detection2d.roi_features import roi_feature_shape, roi_features


class ResizingBackbone:
    """A stand-in for resnet50-c4: a fixed stride-16 map of an image resized by (sx, sy) = (2, 0.5)."""

    channels = 3

    def features(self, image):
        grid = torch.arange(3 * 8 * 10, dtype=torch.float32).reshape(1, 3, 8, 10)
        return grid, (2.0, 0.5)


def test_boxes_are_scaled_into_the_resized_image_then_pooled():
    boxes = np.array([[8.0, 16.0, 40.0, 96.0], [0.0, 0.0, 16.0, 32.0]])
    out = roi_features(ResizingBackbone(), np.zeros((128, 80, 3), np.uint8), boxes, 2, 2)
    assert out.shape == (2, 3, 2, 2) and out.dtype == np.dtype("<f2") and out.flags.c_contiguous
    scaled = torch.tensor([[0, 16.0, 8.0, 80.0, 48.0], [0, 0.0, 0.0, 32.0, 16.0]], dtype=torch.float64)
    expected = roi_align_reference(ResizingBackbone().features(None)[0], scaled, 2, 1 / 16, 2, aligned=True)
    assert np.array_equal(out, expected.to(torch.float16).numpy())


def test_tiny_backbone_features_of_no_box_and_of_some():
    backbone = TinyBackbone(seed=1)
    image = np.random.default_rng(0).integers(0, 256, (90, 160, 3), dtype=np.uint8)
    assert roi_feature_shape(backbone, 7) == (64, 7, 7)
    assert roi_features(backbone, image, np.zeros((0, 4)), 7, 0).shape == (0, 64, 7, 7)
    out = roi_features(backbone, image, np.array([[10.0, 10, 80, 60]]), 7, 0)
    assert out.shape == (1, 64, 7, 7) and np.isfinite(out).all() and out.std() > 0
