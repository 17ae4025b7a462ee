"""Eq. (6) of the paper against hand-computed values."""

import pytest
import torch

from sianms_cli.models.losses import double_margin_loss, negative_terms, pair_distances, positive_terms


def test_terms_by_hand():
    # positive at distance 2.5: ½ (2.5 − 1)² = 1.125; inside α: 0
    assert positive_terms(torch.tensor([2.5, 0.5, 1.0])).tolist() == [1.125, 0.0, 0.0]
    # negative at distance 1: ½ (3 − 1)² = 2; beyond β: 0
    assert negative_terms(torch.tensor([1.0, 3.0, 4.0])).tolist() == [2.0, 0.0, 0.0]


def test_loss_by_hand():
    reference = torch.tensor([[0.0, 0.0], [1.0, 1.0]])
    positive = torch.tensor([[3.0, 4.0], [1.0, 1.5]])  # distances 5 and 0.5
    negative = torch.tensor([[0.0, 2.0], [1.0, 5.0]])  # distances 2 and 4
    # ½ [(5 − 1)² + 0] + ½ [0 + (3 − 2)²] = 8 + 0.5
    assert double_margin_loss(reference, positive, negative).item() == 8.5
    # other margins: α = 0, β = 6 -> ½ (25 + 0.25 + 16 + 4)
    assert double_margin_loss(reference, positive, negative, alpha=0.0, beta=6.0).item() == pytest.approx(22.625)


def test_loss_matches_a_slow_reference():
    generator = torch.Generator().manual_seed(0)
    r, p, n = (torch.randn(16, 5, generator=generator) * 2 for _ in range(3))
    slow = 0.0
    for i in range(16):
        dp = sum((r[i, k] - p[i, k]) ** 2 for k in range(5)) ** 0.5
        dn = sum((r[i, k] - n[i, k]) ** 2 for k in range(5)) ** 0.5
        slow += 0.5 * (max(dp - 1, 0) ** 2 + max(3 - dn, 0) ** 2)
    assert double_margin_loss(r, p, n).item() == pytest.approx(float(slow), rel=1e-5)


def test_gradient_at_zero_distance_is_finite():
    reference = torch.zeros(1, 3, requires_grad=True)
    double_margin_loss(reference, torch.zeros(1, 3), torch.zeros(1, 3)).backward()
    assert torch.isfinite(reference.grad).all()
    assert pair_distances(torch.zeros(2, 3), torch.ones(2, 3)).tolist() == pytest.approx([3 ** 0.5] * 2)
