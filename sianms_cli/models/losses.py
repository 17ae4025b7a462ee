"""The double-margin contrastive loss of the paper, eq. (6).

    L = ½ Σᵢ [ max(‖f(rᵢ) − f(pᵢ)‖₂ − α, 0)² + max(β − ‖f(rᵢ) − f(nᵢ)‖₂, 0)² ],  α = 1, β = 3

Euclidean (not squared) distances, squared hinges, the ½ factor, summed over the batch.
Ready-made contrastive losses (pytorch-metric-learning's among them) use unsquared hinges,
average positives and negatives separately and normalise embeddings by default, which
eq. (6) does not: with normalised embeddings no distance exceeds 2 and β = 3 is never met.
"""

from __future__ import annotations

import torch

ALPHA = 1.0
BETA = 3.0


def pair_distances(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Euclidean distances of aligned rows: (N, d), (N, d) -> (N,).

    The gradient at a zero distance is 0 (torch's norm backward masks it), not NaN.
    """
    return torch.linalg.vector_norm(a - b, dim=-1)


def positive_terms(distance: torch.Tensor, alpha: float = ALPHA) -> torch.Tensor:
    """½ max(d − α, 0)² per pair: zero once a positive is inside radius α."""
    return 0.5 * torch.clamp(distance - alpha, min=0) ** 2


def negative_terms(distance: torch.Tensor, beta: float = BETA) -> torch.Tensor:
    """½ max(β − d, 0)² per pair: zero once a negative is beyond β."""
    return 0.5 * torch.clamp(beta - distance, min=0) ** 2


def double_margin_loss(reference: torch.Tensor, positive: torch.Tensor, negative: torch.Tensor,
                       alpha: float = ALPHA, beta: float = BETA) -> torch.Tensor:
    """Eq. (6) summed over the N triples of embeddings (N, d) each; a scalar tensor."""
    return (positive_terms(pair_distances(reference, positive), alpha).sum()
            + negative_terms(pair_distances(reference, negative), beta).sum())
