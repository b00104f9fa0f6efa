"""Frequency (positional) encoding, gamma(x) in NeRF."""

from __future__ import annotations

import torch
from torch import nn


class PositionalEncoding(nn.Module):
    """``x -> [x, sin(2^k x), cos(2^k x) for k < n_frequencies]`` per coordinate.

    The frequencies are 2^k without a factor of pi (NeuS's choice), suited to coordinates in about [-1, 1].
    """

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
