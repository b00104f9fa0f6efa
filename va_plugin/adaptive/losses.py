"""The paper's attention regularizers, per sample (eqs. 8 and 9), and their weighted reduction."""

from __future__ import annotations

import torch

ALPHA_FLOOR = 1e-8
"""alpha log alpha is evaluated as alpha * log(max(alpha, 1e-8)): 0 at alpha = 0, with a finite gradient."""


def attention_entropy(alpha: torch.Tensor) -> torch.Tensor:
    """``sum_i sum_j alpha_ij log alpha_ij``, averaged over heads: ``[S, H, n, n] -> [S]``; from 0 (rows
    one-hot) down to ``-n log n`` (uniform rows), so minimising it spreads attention (eq. 8)."""
    return (alpha * torch.log(alpha.clamp_min(ALPHA_FLOOR))).sum((-1, -2)).mean(-1)


def feature_consistency(fused: torch.Tensor) -> torch.Tensor:
    """``sum_i || f_fused,i - mean_j f_fused,j ||^2``: ``[S, n, D] -> [S]`` (eq. 9)."""
    centred = fused - fused.mean(dim=1, keepdim=True)
    return (centred * centred).sum((-1, -2))


def weighted_mean(values: torch.Tensor, weights: torch.Tensor | None) -> torch.Tensor:
    """Mean of per-sample ``values [S]`` (the attention's samples, ``[A]``) weighted by (detached) rendering
    ``weights`` of the same shape, a scalar; the plain mean without weights, or when the weights sum to
    (almost) nothing."""
    if values.numel() == 0:
        return values.sum()
    if weights is None or weights.shape != values.shape:
        return values.mean()
    w = weights.detach()
    total = w.sum()
    # no host sync (float(total)) on the hot path: pick the branch on the device
    return torch.where(total > 1e-6, (values * w).sum() / total.clamp_min(1e-6), values.mean())
