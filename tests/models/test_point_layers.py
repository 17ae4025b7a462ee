"""models/point_layers.py: the max pool's gradient routing, and the pooled layer's covariance path
against the per-point layer it replaces, in float64 and in bfloat16."""

import copy

import pytest
import torch

from sianms_cli.models import point_layers
from sianms_cli.models.point_layers import PointLinear, PooledPointLinear, pooled_relu


@pytest.mark.parametrize("points", [64, 20])  # block-wise search; torch's max where N is no multiple of 16
def test_pooled_relu_is_the_originals_max_pool_of_relu_outputs(points):
    """ReLU after the pool instead of before, one maximum per channel taking the gradient: the same
    values and, with duplicated points (as the gathered object points have), the same weight gradients."""
    generator = torch.Generator().manual_seed(4)
    half = torch.randn(3, points // 2, 5, generator=generator, dtype=torch.float64)
    inputs = torch.cat([half, half.flip(1)], dim=1)  # every point twice
    layer = PointLinear(5, 40, relu=False).double().train()
    with torch.no_grad():
        layer.norm.bias[:20] = -4.0  # these channels' outputs below zero at every point
    weights = torch.randn(3, 40, generator=generator, dtype=torch.float64)

    def pooled_and_gradients(pool):
        value = pool(layer(inputs))
        return (value, *torch.autograd.grad((value * weights).sum(), trained_parameters(layer)))

    ours = pooled_and_gradients(pooled_relu)
    original = pooled_and_gradients(lambda x: torch.relu(x).amax(dim=1))
    assert (ours[0] == 0).any() and (ours[0] > 0).any()  # channels below zero everywhere, and above
    for a, b in zip(ours, original):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)


def trained_parameters(layer):
    """A layer's parameters but the linear map's bias, which batch norm cancels in training."""
    return [parameter for name, parameter in layer.named_parameters() if name != "linear.bias"]


def test_training_leaves_out_the_bias_that_batch_norm_cancels():
    """In training: the outputs, gradients and running statistics of linear map + bias -> batch norm;
    the bias reaches the running mean only (momentum and cumulative averages both)."""
    generator = torch.Generator().manual_seed(3)
    x = torch.randn(40, 5, generator=generator, dtype=torch.float64)
    weights = torch.randn(40, 7, generator=generator, dtype=torch.float64)
    for momentum in (0.3, None):
        layer = PointLinear(5, 7).double().train()
        layer.norm.momentum = momentum
        with torch.no_grad():
            layer.linear.bias.copy_(torch.linspace(-2.0, 3.0, 7))
        original = copy.deepcopy(layer)
        plain = torch.nn.Sequential(original.linear, original.norm, torch.nn.ReLU())
        for _ in range(2):  # the second step's running statistics start from the first's
            ours = layer(x)
            theirs = plain(x)
            torch.testing.assert_close(ours, theirs, rtol=1e-12, atol=1e-12)
        gradients = torch.autograd.grad((ours * weights).sum(), list(layer.parameters()), allow_unused=True)
        expected = torch.autograd.grad((theirs * weights).sum(), list(original.parameters()))
        assert gradients[1] is None and float(expected[1].abs().max()) < 1e-12
        for a, b in zip(gradients[::2] + gradients[3:], expected[::2] + expected[3:]):
            torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)
        for name, buffer in layer.norm.named_buffers():
            torch.testing.assert_close(buffer, dict(original.norm.named_buffers())[name], rtol=1e-12, atol=1e-12)
        layer.eval(), original.eval()
        torch.testing.assert_close(layer(x), plain(x), rtol=1e-12, atol=1e-12)


def pooled_layer(dtype=torch.float64, inputs=6, outputs=48):
    """A training-mode pooled layer whose batch norm has negative and positive scales and shifts."""
    torch.manual_seed(0)
    layer = PooledPointLinear(inputs, outputs).to(dtype).train()
    with torch.no_grad():
        layer.norm.weight.copy_(torch.linspace(-1.5, 2.0, outputs))
        layer.norm.bias.copy_(torch.linspace(-1.0, 0.5, outputs))
    return layer


def per_point_path(layer, x):
    """What the pooled layer computes without its covariance path: the per-point layer, then the pool."""
    return pooled_relu(PointLinear.forward(layer, x))


def step(layer, path, x, weights):
    """Output, input gradient and parameter gradients of ``(path(layer, x) * weights).sum()``."""
    x = x.detach().requires_grad_(True)
    value = path(layer, x)
    return (value.detach(), *torch.autograd.grad((value * weights).sum(), [x, *trained_parameters(layer)]))


@pytest.mark.parametrize(("points", "momentum"), [(64, 0.5), (20, None)])
def test_covariance_path_equals_the_per_point_layer_in_float64(points, momentum):
    """Values, gradients of the input, weights, scales and shifts, and the running statistics: the
    same to rounding, with either sign of scale, block-wise and plain maxima."""
    generator = torch.Generator().manual_seed(1)
    x = torch.randn(3, points, 6, generator=generator, dtype=torch.float64) + 0.5
    weights = torch.randn(3, 48, generator=generator, dtype=torch.float64)
    layer = pooled_layer()
    layer.norm.momentum = momentum
    reference = copy.deepcopy(layer)
    assert layer.by_covariance
    ours, theirs = step(layer, PooledPointLinear.forward, x, weights), step(reference, per_point_path, x, weights)
    assert (ours[0] == 0).any() and (ours[0] > 0).any()
    for name, a, b in zip(["value", "input", "weight", "scale", "shift"], ours, theirs):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-10, msg=name)
    for name, buffer in layer.norm.named_buffers():
        torch.testing.assert_close(buffer, dict(reference.norm.named_buffers())[name], rtol=1e-12, atol=0, msg=name)


def test_covariance_path_in_bfloat16_is_as_close_to_float64_as_the_per_point_layer():
    """Under bfloat16 autocast both paths round; the covariance path's outputs and gradients stay
    within twice the per-point layer's distance from the float64 figures (its statistics are float32)."""
    generator = torch.Generator().manual_seed(2)
    x = torch.relu(torch.randn(4, 128, 32, generator=generator))
    weights = torch.randn(4, 256, generator=generator)
    exact = step(pooled_layer(torch.float64, 32, 256), per_point_path, x.double(), weights.double())

    def distances(path):
        layer = pooled_layer(torch.float32, 32, 256)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            result = step(layer, path, x, weights)
        return [float((a.double() - b).norm() / b.norm().clamp(min=1e-12)) for a, b in zip(result, exact)]

    ours, theirs = distances(PooledPointLinear.forward), distances(per_point_path)
    for name, a, b in zip(["value", "input", "weight", "scale", "shift"], ours, theirs):
        assert a <= 2 * b + 1e-3, (name, a, b)


def test_evaluation_and_narrow_layers_take_the_per_point_path(monkeypatch):
    def refuse(*args):
        raise AssertionError("the covariance path ran")

    monkeypatch.setattr(point_layers._CovariancePool, "apply", refuse)
    x = torch.randn(2, 32, 6)
    narrow = PooledPointLinear(6, 12).train()
    assert not narrow.by_covariance
    assert narrow(x).shape == (2, 12)
    wide = pooled_layer(torch.float32).eval()
    torch.testing.assert_close(wide(x), per_point_path(wide, x), rtol=0, atol=0)
