"""What the learned per-view corrections share: one row of parameters per training view, zero at the
start, frozen rows for the conditioning view(s), and a quadratic penalty on the trained entries."""

from __future__ import annotations

from typing import Sequence

import torch
from torch import nn


class PerViewCorrection(nn.Module):
    """``correction [num_views, width]`` (a parameter, zero at the start) and ``trained`` (a 0/1 buffer of
    the same shape: 0 for the rows of ``frozen_views``); subclasses zero more of ``trained`` as they need."""

    def __init__(self, num_views: int, width: int, frozen_views: Sequence[int], penalty_weight: float) -> None:
        super().__init__()
        self.num_views = num_views
        self.penalty_weight = penalty_weight
        self.correction = nn.Parameter(torch.zeros(max(num_views, 1), width))
        trained = torch.ones(max(num_views, 1), width)
        for view in frozen_views:
            if 0 <= view < num_views:
                trained[view] = 0.0
        self.register_buffer("trained", trained, persistent=False)

    def view_index(self, camera_indices: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Which of ``camera_indices [n]`` are training views (bool ``[n]``), and the indices with the
        others (novel views, -1) replaced by 0, safe to gather with."""
        known = (camera_indices >= 0) & (camera_indices < self.num_views)
        return known, torch.where(known, camera_indices, torch.zeros_like(camera_indices))

    def loss(self) -> torch.Tensor:
        """``penalty_weight`` times the mean squared correction over the trained entries."""
        delta = self.correction * self.trained
        count = self.trained.sum().clamp_min(1.0)
        return self.penalty_weight * (delta * delta).sum() / count
