"""Where along each ray to sample: uniform sections and importance (inverse-CDF) sampling."""

from __future__ import annotations

import torch

PDF_PADDING = 1e-5


def uniform_edges(nears: torch.Tensor, fars: torch.Tensor, n_samples: int, jitter: bool,
                  generator: torch.Generator | None = None) -> torch.Tensor:
    """Sample positions ``[n_rays, n_samples]`` spread evenly in [near, far] (``nears, fars [n_rays, 1]``),
    jittered when training."""
    steps = torch.linspace(0.0, 1.0, n_samples + 1, device=nears.device)[:-1]
    steps = steps.expand(nears.shape[0], n_samples)
    if jitter:
        noise = torch.rand(steps.shape, device=nears.device, generator=generator)
    else:
        noise = torch.full_like(steps, 0.5)
    steps = steps + noise / n_samples
    return nears + (fars - nears) * steps


def sample_pdf(bins: torch.Tensor, weights: torch.Tensor, n_samples: int, jitter: bool,
               generator: torch.Generator | None = None) -> torch.Tensor:
    """Draw ``n_samples`` positions ``[n_rays, n_samples]`` in [bins[0], bins[-1]] from the piecewise-constant
    PDF of ``weights [n_rays, n_bins]`` (padded by 1e-5: an all-zero row is uniform) over the sorted bin
    edges ``bins [n_rays, n_bins + 1]``."""
    weights = weights.detach() + PDF_PADDING
    pdf = weights / weights.sum(-1, keepdim=True)
    cdf = torch.cumsum(pdf, dim=-1)
    cdf = torch.cat([torch.zeros_like(cdf[:, :1]), cdf], dim=-1).contiguous()
    if jitter:
        u = torch.rand((cdf.shape[0], n_samples), device=cdf.device, generator=generator)
    else:
        u = torch.linspace(0.5 / n_samples, 1.0 - 0.5 / n_samples, n_samples, device=cdf.device)
        u = u.expand(cdf.shape[0], n_samples)
    u = u.contiguous()
    above = torch.searchsorted(cdf, u, right=True).clamp(1, cdf.shape[-1] - 1)
    below = above - 1
    cdf_lo, cdf_hi = cdf.gather(-1, below), cdf.gather(-1, above)
    bin_lo, bin_hi = bins.gather(-1, below), bins.gather(-1, above)
    span = (cdf_hi - cdf_lo).clamp_min(1e-8)
    return bin_lo + (u - cdf_lo) / span * (bin_hi - bin_lo)
