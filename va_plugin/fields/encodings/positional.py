"""Frequency (positional) encoding, gamma(x) in NeRF."""

from __future__ import annotations

import torch
from torch import nn

from va_plugin.errors import ConfigError


class PositionalEncoding(nn.Module):
    """``x -> [x, sin(2^k x), cos(2^k x) for k < n_frequencies]`` per coordinate (no factor of pi, as
    in NeuS: suited to coordinates in about [-1, 1])."""

    def __init__(self, in_dim: int, n_frequencies: int, include_input: bool = True) -> None:
        super().__init__()
        self.in_dim, self.n_frequencies, self.include_input = in_dim, n_frequencies, include_input
        self.register_buffer("frequencies", 2.0 ** torch.arange(n_frequencies, dtype=torch.float32),
                             persistent=False)

    @property
    def output_dim(self) -> int:
        return self.in_dim * (2 * self.n_frequencies + int(self.include_input))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``[..., in_dim] -> [..., output_dim]``."""
        if self.n_frequencies == 0:
            return x
        scaled = (x[..., None, :] * self.frequencies[:, None]).flatten(-2)
        parts = [x] if self.include_input else []
        return torch.cat(parts + [torch.sin(scaled), torch.cos(scaled)], dim=-1)

    def pull_back(self, x: torch.Tensor, grad_encoding: torch.Tensor) -> torch.Tensor:
        """Chain rule through the encoding: ``grad_encoding [..., output_dim]`` (d/d gamma(x)) becomes
        d/dx ``[..., in_dim]``; elementwise products, differentiable in both arguments."""
        if self.n_frequencies == 0:
            return grad_encoding
        lead, d, n = x.shape[:-1], self.in_dim, self.n_frequencies
        offset = d if self.include_input else 0
        g_sin = grad_encoding[..., offset:offset + n * d].reshape(*lead, n, d)
        g_cos = grad_encoding[..., offset + n * d:].reshape(*lead, n, d)
        freqs = self.frequencies[:, None]
        scaled = x[..., None, :] * freqs
        out = ((g_sin * torch.cos(scaled) - g_cos * torch.sin(scaled)) * freqs).sum(-2)
        return out + grad_encoding[..., :d] if self.include_input else out


def optional_direction_encoding(frequencies: int) -> PositionalEncoding | None:
    """A color network's view-direction encoding from its config value: -1 leaves the direction out
    (None), 0 feeds the raw direction, k > 0 adds k frequency bands."""
    if frequencies < -1:
        raise ConfigError("field.direction_frequencies must be -1 (no direction), 0 or a positive count")
    return PositionalEncoding(3, frequencies) if frequencies >= 0 else None
