"""NeuS-specific numerics: the learned sharpness inv_s and the SDF-to-alpha conversion."""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import nn

INV_S_MIN, INV_S_MAX = 1e-6, 1e6
SDF_BOUND = 1e6
"""SDF estimates are clamped to +-1e6 before they meet inv_s, so an overflowing product cannot turn
the gradient of inv_s into inf * 0 = NaN; sane SDF values never reach it."""


class SingleVariance(nn.Module):
    """One learned scalar ``v`` with ``inv_s = exp(10 v)``, clamped to [1e-6, 1e6]."""

    def __init__(self, init: float = 0.3) -> None:
        super().__init__()
        self.variance = nn.Parameter(torch.tensor(float(init)))

    def inv_s(self) -> torch.Tensor:
        """The sharpness ``inv_s = exp(10 v)``, a scalar tensor clamped to [INV_S_MIN, INV_S_MAX]."""
        log_bound = math.log(INV_S_MAX)
        return torch.exp((10.0 * self.variance).clamp(-log_bound, log_bound)).clamp(INV_S_MIN, INV_S_MAX)


def neus_alpha(sdf: torch.Tensor, true_cos: torch.Tensor, deltas: torch.Tensor, inv_s: torch.Tensor,
               cos_anneal_ratio: float) -> torch.Tensor:
    """Alpha ``[n_rays, n_samples]`` in [0, 1] of each section from the SDF at its mid-point (NeuS,
    Wang et al. 2021, eq. 13); ``sdf, true_cos, deltas`` are ``[n_rays, n_samples]``, ``inv_s`` a scalar
    tensor. The section ends' SDF comes from the ray/normal cosine, annealed from "always half-visible"
    to the true one."""
    iter_cos = -(torch.relu(-true_cos * 0.5 + 0.5) * (1.0 - cos_anneal_ratio)
                 + torch.relu(-true_cos) * cos_anneal_ratio)
    prev_sdf = (sdf - iter_cos * deltas * 0.5).clamp(-SDF_BOUND, SDF_BOUND)
    next_sdf = (sdf + iter_cos * deltas * 0.5).clamp(-SDF_BOUND, SDF_BOUND)
    prev_cdf = torch.sigmoid(prev_sdf * inv_s)
    next_cdf = torch.sigmoid(next_sdf * inv_s)
    return ((prev_cdf - next_cdf + 1e-5) / (prev_cdf + 1e-5)).clamp(0.0, 1.0)


def section_alpha(sdf_edges: torch.Tensor, inv_s: float) -> torch.Tensor:
    """Alpha ``[n_rays, n_samples]`` of each section from the SDF at its edges ``[n_rays, n_samples + 1]``
    (used when up-sampling, no normals needed)."""
    sdf_edges = sdf_edges.clamp(-SDF_BOUND, SDF_BOUND)
    prev_cdf = torch.sigmoid(sdf_edges[:, :-1] * inv_s)
    next_cdf = torch.sigmoid(sdf_edges[:, 1:] * inv_s)
    return ((prev_cdf - next_cdf + 1e-5) / (prev_cdf + 1e-5)).clamp(0.0, 1.0)


def sdf_band(coarse_edges: torch.Tensor, coarse_sdf: torch.Tensor, t_mid: torch.Tensor, inv_s: torch.Tensor,
             margin: float) -> torch.Tensor:
    """Which samples may lie near the surface, from the SDF known at the coarse edges (no gradients).

    A sample in the coarse section ``[e_j, e_j+1]`` is outside the band when the SDF's lower bound
    there, ``min(sdf_j, sdf_j+1) - (e_j+1 - e_j)`` (for ``|grad sdf| <= 1``), exceeds ``margin / inv_s``;
    its alpha is then at most about ``1e-5 + exp(-margin)``. ``coarse_edges, coarse_sdf``: ``[n_rays, m]``
    sorted positions and their SDF; ``t_mid``: ``[n_rays, n]`` samples to test; returns ``[n_rays, n]``
    bool, True for samples to evaluate.
    """
    steps = coarse_edges[:, 1:] - coarse_edges[:, :-1]
    lowest = torch.minimum(coarse_sdf[:, :-1], coarse_sdf[:, 1:]) - steps  # [n_rays, m - 1]
    section = torch.searchsorted(coarse_edges.contiguous(), t_mid.contiguous(), right=True) - 1
    section = section.clamp(0, steps.shape[1] - 1)
    return lowest.gather(1, section) * inv_s < margin


def surface_crossings(sdf_fn: Callable[[torch.Tensor], torch.Tensor], origins: torch.Tensor,
                      directions: torch.Tensor, nears: torch.Tensor, fars: torch.Tensor,
                      n_samples: int, band: float | None = 6.0) -> torch.Tensor:
    """Half the number of times each line crosses the zero level set of ``sdf_fn``, ``[n_rays]``.

    The lines run from ``nears`` to ``fars`` (``[n_rays, 1]``) along ``origins + t directions``; the SDF
    (``[..., 3]`` -> ``[...]``, negative inside) at ``n_samples`` stratified points becomes a soft inside
    indicator ``sigmoid(-sdf / w)`` (``w``: the spacing) whose total variation is halved: 1 through a
    convex body, 2 for a line that leaves and re-enters, 0 for a miss.

    With ``band`` (and autograd recording) only points with ``|sdf| < band w`` are evaluated with a graph
    (same value; the saturated points' gradient share is below ``sigmoid'(band)``). ``None``: every point."""
    n_rays = origins.shape[0]
    offsets = torch.arange(n_samples, device=origins.device, dtype=origins.dtype)
    u = (offsets + torch.rand(n_rays, n_samples, device=origins.device, dtype=origins.dtype)) / n_samples
    t = nears + (fars - nears) * u
    width = ((fars - nears) / n_samples).clamp_min(1e-6)
    points = origins[:, None, :] + directions[:, None, :] * t[..., None]
    if band is None or not torch.is_grad_enabled():
        sdf = sdf_fn(points)
    else:
        with torch.no_grad():
            sdf = sdf_fn(points)
        near = (sdf.abs() < band * width).nonzero(as_tuple=True)
        if near[0].numel() > 0:
            sdf = sdf.index_put(near, sdf_fn(points[near]))
    inside = torch.sigmoid(-sdf / width)
    return 0.5 * (inside[:, 1:] - inside[:, :-1]).abs().sum(-1)
