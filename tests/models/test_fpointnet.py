"""models/fpointnet.py: output shapes for several point counts, the masking gather, parameter count,
the segmentation head's split first layer."""

import pytest
import torch

from sianms_cli.models.fpointnet import FPointNetV1, gather_object_points

MEAN_SIZES = torch.tensor([[4.6, 1.95, 1.72], [0.73, 0.67, 1.77], [1.70, 0.60, 1.28]])


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return FPointNetV1(MEAN_SIZES).eval()


@pytest.mark.parametrize("points", [1, 7, 300, 1024])
def test_output_shapes(model, points):
    batch = 3
    generator = torch.Generator().manual_seed(1)
    x = torch.randn(batch, points, 4, generator=generator)
    one_hot = torch.eye(3)[[0, 1, 2]]
    with torch.no_grad():
        out = model(x, one_hot, generator=generator)
    expected = {
        "seg_logits": (batch, points, 2), "mask": (batch, points), "mask_mean": (batch, 3),
        "center_delta": (batch, 3), "stage1_center": (batch, 3), "center": (batch, 3),
        "heading_scores": (batch, 12), "heading_residuals_normalized": (batch, 12), "heading_residuals": (batch, 12),
        "size_scores": (batch, 3), "size_residuals_normalized": (batch, 3, 3), "size_residuals": (batch, 3, 3),
    }
    assert {k: tuple(v.shape) for k, v in out.items()} == expected
    assert torch.allclose(out["heading_residuals"], out["heading_residuals_normalized"] * torch.pi / 12)
    assert torch.allclose(out["size_residuals"], out["size_residuals_normalized"] * MEAN_SIZES[None])
    assert torch.allclose(out["center"] - out["stage1_center"] + out["stage1_center"], out["center"])


def test_v1_has_the_original_size_and_box_output_width(model):
    # 3 + 2 NH + 4 NS = 3 + 24 + 12 = 39 outputs with NS = 3 (docs/methods.md#heading-bins-and-size-clusters);
    # ~1.6 M parameters.
    assert model.box_head[-1].out_features == 39
    parameters = sum(p.numel() for p in model.parameters())
    assert 1.5e6 < parameters < 1.8e6


def test_without_intensity_takes_three_channels():
    model = FPointNetV1(MEAN_SIZES, in_channels=3).eval()
    with torch.no_grad():
        out = model(torch.randn(2, 50, 3), torch.eye(3)[:2])
    assert out["center"].shape == (2, 3)


def test_gather_keeps_only_masked_points_and_repeats_when_few():
    xyz = torch.arange(10, dtype=torch.float32)[None, :, None].expand(2, 10, 3).contiguous()
    mask = torch.zeros(2, 10, dtype=torch.bool)
    mask[0, [2, 5, 7]] = True  # fewer than asked: all of them, plus repeats
    generator = torch.Generator().manual_seed(0)
    gathered = gather_object_points(xyz, mask, 6, generator)
    assert set(gathered[0, :, 0].tolist()) == {2.0, 5.0, 7.0}
    assert gathered[1].eq(0).all()  # no masked point: copies of point 0


def test_gather_subsets_without_replacement_when_many():
    xyz = torch.arange(20, dtype=torch.float32)[None, :, None].expand(1, 20, 3).contiguous()
    mask = torch.ones(1, 20, dtype=torch.bool)
    mask[0, :5] = False
    gathered = gather_object_points(xyz, mask, 8, torch.Generator().manual_seed(0))[0, :, 0]
    assert len(set(gathered.tolist())) == 8 and gathered.min() >= 5


def test_bn_momentum_is_settable(model):
    model.set_bn_momentum(0.25)
    assert {m.momentum for m in model.modules() if isinstance(m, torch.nn.BatchNorm1d)} == {0.25}


def test_segmentation_head_is_the_originals_concatenation(model):
    """The head's first layer applied per frustum to the global part gives the original's per-point
    linear map on [point feature, tiled global feature], in value and in gradient."""
    generator = torch.Generator().manual_seed(2)
    xyz = torch.randn(3, 50, 4, generator=generator).requires_grad_(True)
    one_hot = torch.eye(3)[[0, 1, 2]]
    point_feature = model.seg_point(xyz)
    global_feature = torch.cat([model.seg_global(point_feature), one_hot.float()], dim=1)
    tiled = global_feature[:, None, :].expand(-1, xyz.shape[1], -1)
    original = model.seg_head(torch.cat([point_feature, tiled], dim=2))
    (original_grad,) = torch.autograd.grad(original.square().sum(), xyz)
    ours = model(xyz, one_hot)["seg_logits"]
    (ours_grad,) = torch.autograd.grad(ours.square().sum(), xyz)
    torch.testing.assert_close(ours, original, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(ours_grad, original_grad, rtol=1e-4, atol=1e-5)
