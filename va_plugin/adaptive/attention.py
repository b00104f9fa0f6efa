"""Multi-head self-attention across the n view features of each sample (the paper's eqs. 5-7, 10-12)."""

from __future__ import annotations

import math

import torch
from torch import nn

from va_plugin.errors import ConfigError

LOGIT_BOUND = 50.0
"""Attention logits are clamped to [-50, 50] (softmax is exact to fp32 there) so an overflow cannot
produce inf - inf = NaN."""


class ViewAttention(nn.Module):
    """``f_fused,i = f_i + W_o [sum_j alpha^h_ij v^h_j]_h`` for each sample, over its n view tokens.

    The residual connection and the zero-initialised output projection (not in the paper's eq. 12)
    make phase 3 start from phase 2's renders.

    Args:
        feature_dim: token width D (the branch output).
        attention_dim: total width of the query/key/value projections (split over the heads).
        n_heads: H.
    """

    def __init__(self, feature_dim: int, attention_dim: int = 128, n_heads: int = 4) -> None:
        super().__init__()
        if attention_dim % n_heads != 0:
            raise ConfigError(f"attention_dim ({attention_dim}) must be a multiple of attention_heads ({n_heads})")
        self.n_heads, self.head_dim = n_heads, attention_dim // n_heads
        self.qkv = nn.Linear(feature_dim, 3 * attention_dim)
        self.out = nn.Linear(attention_dim, feature_dim)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, tokens: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``tokens [S, n, D]`` -> (fused ``[S, n, D]``, attention weights ``[S, H, n, n]``, rows sum to 1)."""
        s, n, _ = tokens.shape
        # split on the last dimension: the backward joins the three gradients with one concatenation
        q, k, v = (part.view(s, n, self.n_heads, self.head_dim).transpose(1, 2)
                   for part in self.qkv(tokens).split(self.n_heads * self.head_dim, dim=-1))
        logits = (q @ k.transpose(-1, -2)) / math.sqrt(self.head_dim)
        alpha = torch.softmax(logits.clamp(-LOGIT_BOUND, LOGIT_BOUND), dim=-1)
        heads = (alpha @ v).transpose(1, 2).reshape(s, n, self.n_heads * self.head_dim)
        return tokens + self.out(heads), alpha


def reference_attention(module: ViewAttention, tokens: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The same computation written out with loops over samples, heads and views (for tests only):
    ``tokens [n_samples, n_views, feature_dim]`` -> (fused tokens of the same shape, attention
    ``[n_samples, n_heads, n_views, n_views]``)."""
    s, n, _ = tokens.shape
    h, dh = module.n_heads, module.head_dim
    w, b = module.qkv.weight, module.qkv.bias
    fused = torch.zeros_like(tokens)
    alphas = torch.zeros(s, h, n, n, dtype=tokens.dtype, device=tokens.device)
    for si in range(s):
        concat = torch.zeros(n, h * dh, dtype=tokens.dtype, device=tokens.device)
        for hi in range(h):
            rows = lambda part, hi=hi: slice(part * h * dh + hi * dh, part * h * dh + (hi + 1) * dh)
            q = [w[rows(0)] @ tokens[si, i] + b[rows(0)] for i in range(n)]
            k = [w[rows(1)] @ tokens[si, j] + b[rows(1)] for j in range(n)]
            v = [w[rows(2)] @ tokens[si, j] + b[rows(2)] for j in range(n)]
            for i in range(n):
                logits = torch.stack([torch.dot(q[i], k[j]) / math.sqrt(dh) for j in range(n)])
                weights = torch.exp(logits - logits.max())
                weights = weights / weights.sum()
                alphas[si, hi, i] = weights
                concat[i, hi * dh:(hi + 1) * dh] = sum(weights[j] * v[j] for j in range(n))
        fused[si] = tokens[si] + concat @ module.out.weight.T + module.out.bias
    return fused, alphas
