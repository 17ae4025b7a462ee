import itertools

import pytest
import torch

from sianms_cli.detection2d.roi_align import roi_align, roi_align_reference
from sianms_cli.errors import SianmsError


def ramp(height=4, width=5):
    """f[y, x] = 10 y + x: bilinear interpolation of it is exact, so values are easy by hand."""
    y, x = torch.meshgrid(torch.arange(height, dtype=torch.float64), torch.arange(width, dtype=torch.float64),
                          indexing="ij")
    return (10 * y + x)[None, None]


def test_hand_computed_aligned_values():
    # Box [1, 1, 3, 3], aligned: shift by 0.5 -> [0.5, 2.5]; 1x1 output, 2x2 samples at 1.0 and 2.0
    # on each axis -> mean of f at (1,1), (1,2), (2,1), (2,2) = 16.5.
    out = roi_align(ramp(), torch.tensor([[0, 1.0, 1.0, 3.0, 3.0]]), 1, 1.0, 2, aligned=True)
    assert out.item() == pytest.approx(16.5)
    # 2x2 output, one sample per bin: bins centred at 1.0 and 2.0 -> f exactly there.
    out = roi_align(ramp(), torch.tensor([[0, 1.0, 1.0, 3.0, 3.0]]), 2, 1.0, 1, aligned=True)
    assert torch.allclose(out[0, 0], torch.tensor([[11.0, 12.0], [21.0, 22.0]], dtype=torch.float64))
    # Not aligned: [1, 3], one sample per bin at 1.5 and 2.5 -> f(1.5, 1.5) = 16.5 etc.
    out = roi_align(ramp(), torch.tensor([[0, 1.0, 1.0, 3.0, 3.0]]), 2, 1.0, 1, aligned=False)
    assert torch.allclose(out[0, 0], torch.tensor([[16.5, 17.5], [26.5, 27.5]], dtype=torch.float64))


def test_spatial_scale_and_border_rules():
    # spatial_scale 0.5, box [2, 2, 6, 6] -> [1, 3] -0.5 = [0.5, 2.5], same as the first case.
    out = roi_align(ramp(), torch.tensor([[0, 2.0, 2.0, 6.0, 6.0]]), 1, 0.5, 2, aligned=True)
    assert out.item() == pytest.approx(16.5)
    # A sample beyond the last row/column reads the edge pixel: box around x = 4.6 (W = 5).
    out = roi_align(ramp(), torch.tensor([[0, 4.9, 0.9, 5.3, 1.1]]), 1, 1.0, 1, aligned=True)
    assert out.item() == pytest.approx(10 * 0.5 + 4)  # y = 0.5, x clamped to column 4
    # x in [-2, 0] -> [-2.5, -0.5]: samples at x = -2 (left of -1: reads 0) and x = -1 (valid,
    # clamped to column 0); y = 1.5 - 0.5 = 1 -> row 1.
    out = roi_align(ramp(), torch.tensor([[0, -2.0, 1.5, 0.0, 1.5]]), (1, 2), 1.0, 1, aligned=True)
    assert out[0, 0, 0].tolist() == pytest.approx([0.0, 10.0])
    # With two samples per bin, the invalid one still counts in the average.
    out = roi_align(ramp(), torch.tensor([[0, -2.0, 1.5, 0.0, 1.5]]), 1, 1.0, (2), aligned=True)
    assert out.item() == pytest.approx(0.25 * (0 + 0 + 10 + 10))


def test_empty_box_gives_zeros_and_no_rois_gives_empty():
    assert roi_align(ramp(), torch.tensor([[0, 2.0, 2.0, 2.0, 2.0]]), 3, 1.0, -1, aligned=True).abs().sum() == 0
    assert roi_align(ramp(), torch.zeros((0, 5)), 3).shape == (0, 1, 3, 3)


@pytest.mark.parametrize("aligned", [True, False])
def test_matches_slow_reference(aligned):
    generator = torch.Generator().manual_seed(0)
    features = torch.randn(2, 3, 7, 9, generator=generator, dtype=torch.float64)
    count = 60
    xy = torch.rand(count, 2, generator=generator) * 12 - 2
    wh = torch.rand(count, 2, generator=generator) * 7
    wh[:10] *= 0.05  # thinner than a pixel
    rois = torch.cat([torch.randint(0, 2, (count, 1), generator=generator).double(), xy, xy + wh], 1)
    rois[3, 3] = rois[3, 1] - 0.2  # inverted box
    for ratio, size, scale in itertools.product([-1, 0, 1, 2, 4], [1, 3, (2, 3)], [1.0, 0.5]):
        fast = roi_align(features, rois, size, scale, ratio, aligned)
        slow = roi_align_reference(features, rois, size, scale, ratio, aligned)
        assert torch.allclose(fast, slow, atol=1e-12), (ratio, size, scale)


def test_list_of_boxes_and_float32():
    features = torch.randn(2, 4, 6, 6)
    a = roi_align(features, [torch.tensor([[0.0, 0, 4, 4]]), torch.tensor([[1.0, 1, 5, 5]])], 2)
    b = roi_align(features, torch.tensor([[0, 0.0, 0, 4, 4], [1, 1, 1, 5, 5]]), 2)
    assert a.dtype == torch.float32 and torch.equal(a, b)


def test_bad_shapes_fail_clearly():
    with pytest.raises(SianmsError, match="features"):
        roi_align(torch.zeros(3, 4, 4), torch.zeros((1, 5)), 2)
    with pytest.raises(SianmsError, match="boxes"):
        roi_align(torch.zeros(1, 3, 4, 4), torch.zeros((1, 4)), 2)
