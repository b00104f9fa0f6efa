"""NeuS-specific numerics: the learned sharpness inv_s and the SDF-to-alpha conversion."""

from __future__ import annotations

import math
from typing import Callable, Optional

import torch
from torch import nn

INV_S_MIN, INV_S_MAX = 1e-6, 1e6
SDF_BOUND = 1e6
"""SDF estimates are clamped to +-1e6 before they meet inv_s: sigmoid is flat long before (a surface
farther than 1e6 scene units is no surface), and a product that overflowed to inf would turn the
gradient of inv_s into inf * 0 = NaN. Sane SDF values never reach the bound, so they are unchanged."""


class SingleVariance(nn.Module):
    """One learned scalar ``v`` with ``inv_s = exp(10 v)``, clamped to [1e-6, 1e6]."""

    def __init__(self, init: float = 0.3) -> None:
        super().__init__()
        self.variance = nn.Parameter(torch.tensor(float(init)))

    def inv_s(self) -> torch.Tensor:
        log_bound = math.log(INV_S_MAX)
        return torch.exp((10.0 * self.variance).clamp(-log_bound, log_bound)).clamp(INV_S_MIN, INV_S_MAX)


def neus_alpha(sdf: torch.Tensor, true_cos: torch.Tensor, deltas: torch.Tensor, inv_s: torch.Tensor,
               cos_anneal_ratio: float) -> torch.Tensor:
    """Alpha of each section from the SDF at its mid-point (NeuS, Wang et al. 2021, eq. 13).

    The SDF at the section ends is estimated from the mid-point value and the ray/normal cosine;
    the cosine is annealed from "always half-visible" to the true cosine so early training does not
    see through surfaces.

    Args:
        sdf, true_cos, deltas: ``[n_rays, n_samples]``.
        inv_s: scalar tensor.
    Returns:
        alpha ``[n_rays, n_samples]`` in [0, 1].
    """
    iter_cos = -(torch.relu(-true_cos * 0.5 + 0.5) * (1.0 - cos_anneal_ratio)
                 + torch.relu(-true_cos) * cos_anneal_ratio)
    prev_sdf = (sdf - iter_cos * deltas * 0.5).clamp(-SDF_BOUND, SDF_BOUND)
    next_sdf = (sdf + iter_cos * deltas * 0.5).clamp(-SDF_BOUND, SDF_BOUND)
    prev_cdf = torch.sigmoid(prev_sdf * inv_s)
    next_cdf = torch.sigmoid(next_sdf * inv_s)
    return ((prev_cdf - next_cdf + 1e-5) / (prev_cdf + 1e-5)).clamp(0.0, 1.0)


def section_alpha(sdf_edges: torch.Tensor, inv_s: float) -> torch.Tensor:
    """Alpha of each section from the SDF at its two ends (used when up-sampling, no normals needed).

    Args:
        sdf_edges: ``[n_rays, n_samples + 1]`` SDF at the section edges.
    Returns:
        ``[n_rays, n_samples]``.
    """
    sdf_edges = sdf_edges.clamp(-SDF_BOUND, SDF_BOUND)
    prev_cdf = torch.sigmoid(sdf_edges[:, :-1] * inv_s)
    next_cdf = torch.sigmoid(sdf_edges[:, 1:] * inv_s)
    return ((prev_cdf - next_cdf + 1e-5) / (prev_cdf + 1e-5)).clamp(0.0, 1.0)


def sdf_band(coarse_edges: torch.Tensor, coarse_sdf: torch.Tensor, t_mid: torch.Tensor, inv_s: torch.Tensor,
             margin: float) -> torch.Tensor:
    """Which samples may lie near the surface, from the SDF known at the coarse edges (no gradients).

    A sample at ``t_mid`` inside the coarse section ``[e_j, e_j+1]`` is outside the band when the SDF
    stays above ``margin / inv_s`` over that whole section. With ``|grad sdf| <= 1`` the SDF there is at
    least ``min(sdf_j, sdf_j+1) - (e_j+1 - e_j)``; the full section length (not half) also covers the
    ends of the sample's own section, where NeuS evaluates Phi. Outside the band alpha is at most
    about ``1e-5 + exp(-margin)`` (the 1e-5 is the floor of NeuS's alpha formula), so dropping those
    samples changes a ray's accumulation by at most about 1e-5 per sample.

    Args:
        coarse_edges, coarse_sdf: ``[n_rays, m]`` sorted positions along each ray and their SDF.
        t_mid: ``[n_rays, n]`` positions of the samples to test.
        inv_s: scalar tensor (NeuS's sharpness).
    Returns:
        ``[n_rays, n]`` bool, True for samples to evaluate.
    """
    steps = coarse_edges[:, 1:] - coarse_edges[:, :-1]
    lowest = torch.minimum(coarse_sdf[:, :-1], coarse_sdf[:, 1:]) - steps  # [n_rays, m - 1]
    section = torch.searchsorted(coarse_edges.contiguous(), t_mid.contiguous(), right=True) - 1
    section = section.clamp(0, steps.shape[1] - 1)
    return lowest.gather(1, section) * inv_s < margin


def surface_crossings(sdf_fn: Callable[[torch.Tensor], torch.Tensor], origins: torch.Tensor,
                      directions: torch.Tensor, nears: torch.Tensor, fars: torch.Tensor,
                      n_samples: int, band: Optional[float] = 6.0) -> torch.Tensor:
    """Half the number of times each line crosses the zero level set of ``sdf_fn``, ``[n_rays]``.

    The lines run from ``nears`` to ``fars`` (``[n_rays, 1]``) along ``origins + t directions``; the SDF
    (negative inside) is taken at ``n_samples`` stratified points on each, turned into a soft inside
    indicator ``sigmoid(-sdf / w)`` with ``w`` the points' spacing, and the indicator's total variation is
    halved: 1 for a line that goes through a convex body, 2 for one that leaves the surface and enters it
    again, 0 for one that misses. Its gradient sits at the indicator's local extrema: a grazing line's
    peak (pushed out) and the gap between two entries (pushed in). ``sdf_fn`` maps ``[..., 3]`` to
    ``[...]``. A line of zero length (a miss) has a saturated indicator and contributes nothing.

    With ``band`` (and autograd recording), the SDF is first taken at every point without a graph, and
    only the points with ``|sdf| < band w`` are taken again with one: the value is the same, and the
    gradient leaves out the saturated points, whose share is below ``sigmoid'(band)`` (0.25% of the peak at
    6). Most points of most lines are far from the surface, so this saves most of the backward pass.
    ``None`` takes every point with a graph."""
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
