"""models/fpointnet_losses.py: encodings round trip; the loss on hand-made boxes."""

import math

import pytest
import torch

from sianms_cli.models.fpointnet_losses import (
    angle_to_class,
    box_corners,
    class_to_angle,
    decode_boxes,
    fpointnet_loss,
    huber,
)

NH = 12
MEAN = torch.tensor([[4.0, 2.0, 1.5], [0.8, 0.6, 1.7], [1.7, 0.6, 1.3]], dtype=torch.float64)


def test_heading_bins_hand_cases():
    angles = torch.tensor([0.0, math.radians(16), math.radians(-15), math.radians(14.999), math.pi],
                          dtype=torch.float64)
    bins, residual = angle_to_class(angles, NH)
    assert bins.tolist() == [0, 1, 0, 0, 6]
    expected = torch.tensor([0.0, -14.0, -15.0, 14.999, 0.0], dtype=torch.float64)
    assert torch.allclose(torch.rad2deg(residual), expected, atol=1e-9)


def test_heading_round_trip():
    angles = torch.linspace(-3 * math.pi, 3 * math.pi, 1001, dtype=torch.float64)
    bins, residual = angle_to_class(angles, NH)
    assert bins.min() >= 0 and bins.max() <= NH - 1
    assert (residual >= -math.pi / NH - 1e-12).all() and (residual < math.pi / NH + 1e-12).all()
    decoded = class_to_angle(bins, residual, NH)
    assert (decoded > -math.pi).all() and (decoded <= math.pi + 1e-12).all()
    difference = torch.remainder(decoded - angles + math.pi, 2 * math.pi) - math.pi
    assert difference.abs().max() < 1e-9


def test_huber_hand_values():
    assert huber(torch.tensor([3.0]), 2.0).item() == pytest.approx(0.5 * 4 + 2 * 1)
    assert huber(torch.tensor([0.5, -0.5]), 1.0).item() == pytest.approx(0.125)


def test_corners_of_a_box_and_its_flip_are_the_same_set():
    center = torch.tensor([[1.0, 0.5, 10.0]], dtype=torch.float64)
    lwh = torch.tensor([[4.0, 2.0, 1.5]], dtype=torch.float64)
    corners = box_corners(center, torch.tensor([0.0], dtype=torch.float64), lwh)[0]
    # heading 0: corner 0 is (+l/2, +h/2, +w/2), corner 6 is its opposite (docs/methods.md#box-corners)
    assert corners[0].tolist() == [3.0, 1.25, 11.0] and corners[6].tolist() == [-1.0, -0.25, 9.0]
    assert torch.allclose((corners[0] + corners[6]) / 2, center[0])
    flipped = box_corners(center, torch.tensor([math.pi], dtype=torch.float64), lwh)[0]
    assert torch.cdist(corners, flipped).min(dim=1).values.max() < 1e-12


def perfect_outputs(targets, seg_logit=20.0):
    """Network outputs that encode exactly the targets (the loss's encodings inverted)."""
    batch, points = targets["seg"].shape
    bins, residual = angle_to_class(targets["heading"], NH)
    heading_norm = torch.zeros(batch, NH, dtype=torch.float64)
    heading_norm[torch.arange(batch), bins] = residual / (math.pi / NH)
    size_norm = torch.zeros(batch, 3, 3, dtype=torch.float64)
    mean = MEAN[targets["size_class"]]
    size_norm[torch.arange(batch), targets["size_class"]] = (targets["lwh"] - mean) / mean
    seg_logits = torch.zeros(batch, points, 2, dtype=torch.float64)
    seg_logits[..., 1] = torch.where(targets["seg"] == 1, seg_logit, -seg_logit)
    return {
        "seg_logits": seg_logits, "center": targets["center"].clone(), "stage1_center": targets["center"].clone(),
        "heading_scores": 50.0 * torch.nn.functional.one_hot(bins, NH).double(),
        "heading_residuals_normalized": heading_norm, "heading_residuals": heading_norm * math.pi / NH,
        "size_scores": 50.0 * torch.nn.functional.one_hot(targets["size_class"], 3).double(),
        "size_residuals_normalized": size_norm, "size_residuals": size_norm * MEAN[None],
    }


@pytest.fixture
def targets():
    return {
        "seg": torch.tensor([[1, 0, 1, 0], [0, 0, 1, 1]]),
        "center": torch.tensor([[0.5, 1.0, 12.0], [-1.0, 0.7, 25.0]], dtype=torch.float64),
        "heading": torch.tensor([0.4, -2.9], dtype=torch.float64),
        "lwh": torch.tensor([[4.3, 1.9, 1.6], [0.7, 0.65, 1.8]], dtype=torch.float64),
        "size_class": torch.tensor([0, 1]),
    }


def test_a_perfect_prediction_has_zero_box_losses(targets):
    losses = fpointnet_loss(perfect_outputs(targets), targets, MEAN)
    for term in ("center", "stage1_center", "heading_residual", "size_residual", "corner"):
        assert losses[term].item() == pytest.approx(0.0, abs=1e-12), term
    for term in ("mask", "heading_class", "size_class"):
        assert 0 <= losses[term].item() < 1e-8, term


def test_size_and_heading_decode_round_trip(targets):
    decoded = decode_boxes(perfect_outputs(targets), MEAN, NH)
    assert torch.allclose(decoded["lwh"], targets["lwh"])
    assert torch.allclose(decoded["heading"], targets["heading"])
    assert decoded["size_class"].tolist() == [0, 1]


def test_a_heading_flipped_prediction_has_zero_corner_loss(targets):
    outputs = perfect_outputs(targets)
    bins, _ = angle_to_class(targets["heading"], NH)
    rows = torch.arange(2)
    outputs["heading_residuals_normalized"][rows, bins] += NH  # + pi in radians
    outputs["heading_residuals"] = outputs["heading_residuals_normalized"] * math.pi / NH
    losses = fpointnet_loss(outputs, targets, MEAN)
    assert losses["corner"].item() == pytest.approx(0.0, abs=1e-9)
    assert losses["heading_residual"].item() == pytest.approx(NH - 0.5)  # Huber(12, 1)


def test_the_heading_class_weight_scales_only_the_heading_bin_term_inside_lambda(targets):
    outputs = perfect_outputs(targets)
    outputs["heading_scores"] = torch.zeros_like(outputs["heading_scores"])  # a uniform guess: ln 12 each
    plain = fpointnet_loss(outputs, targets, MEAN, box_weight=2.0)
    weighted = fpointnet_loss(outputs, targets, MEAN, box_weight=2.0, heading_class_weight=5.0)
    assert plain["heading_class"].item() == pytest.approx(math.log(NH))
    assert (weighted["total"] - plain["total"]).item() == pytest.approx(2.0 * 4.0 * math.log(NH))
    assert all(torch.equal(weighted[term], plain[term]) for term in plain if term != "total")


def test_hand_computed_shift_case():
    """One 4 x 2 x 1.5 box at heading 0, predicted 3 m off along x, stage 1 0.5 m off, logits 0.

    Corner distances: 3 to its own corner; to the flipped box's corner (-sx, sy, -sz) it is
    |(4 sx + 3, 0, 2 sz)|, √5 for the rear corners (sx = -1). Huber(3) = 2.5, Huber(√5) = √5 - 0.5.
    """
    targets = {"seg": torch.tensor([[1, 0]]), "center": torch.tensor([[0.0, 0.0, 10.0]], dtype=torch.float64),
               "heading": torch.tensor([0.0], dtype=torch.float64),
               "lwh": torch.tensor([[4.0, 2.0, 1.5]], dtype=torch.float64), "size_class": torch.tensor([0])}
    outputs = perfect_outputs(targets, seg_logit=0.0)
    outputs["center"] = outputs["center"] + torch.tensor([[3.0, 0.0, 0.0]], dtype=torch.float64)
    outputs["stage1_center"] = outputs["stage1_center"] + torch.tensor([[0.0, 0.5, 0.0]], dtype=torch.float64)
    losses = fpointnet_loss(outputs, targets, MEAN)
    corner = (2.5 + (math.sqrt(5) - 0.5)) / 2
    assert losses["mask"].item() == pytest.approx(math.log(2))
    assert losses["center"].item() == pytest.approx(4.0)
    assert losses["stage1_center"].item() == pytest.approx(0.125)
    assert losses["corner"].item() == pytest.approx(corner)
    terms = sum(losses[k] for k in ("center", "stage1_center", "heading_class", "size_class"))
    residuals = losses["heading_residual"] + losses["size_residual"]
    expected = losses["mask"] + terms + 20 * residuals + 10 * losses["corner"]
    assert losses["total"].item() == pytest.approx(expected.item())
