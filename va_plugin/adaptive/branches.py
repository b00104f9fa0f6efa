"""Per-view MLP branches F_view,i (the paper's eq. 4), all views in one batched operation.

Each branch is residual, ``f_i = f_shared + B_i(f_shared)``, with its last layer at zero, so phase 2
starts by rendering exactly what the shared network rendered.
"""

from __future__ import annotations

import itertools
import math

import torch
from torch import nn

from va_plugin.errors import ConfigError
from va_plugin.utils.stages import timed


class ViewBranches(nn.Module):
    """``n_views`` residual MLPs of ``n_layers`` linear layers (``width`` hidden units), weights stacked.

    Args:
        n_views: number of training views n.
        feature_dim: width D of f_shared (input and output of every branch).
        width: hidden width of a branch (the paper: 128).
        n_layers: linear layers per branch, at least 1 (the paper: 3).
    """

    def __init__(self, n_views: int, feature_dim: int, width: int = 128, n_layers: int = 3) -> None:
        super().__init__()
        if n_views < 1 or n_layers < 1:
            raise ConfigError(f"the view branches need at least one view and branch_layers >= 1, got {n_views} views "
                              f"and {n_layers} layers")
        self.n_views, self.feature_dim = n_views, feature_dim
        dims = [feature_dim] + [width] * (n_layers - 1) + [feature_dim]
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for k, (a, b) in enumerate(itertools.pairwise(dims)):
            bound = 1.0 / math.sqrt(a)
            w = torch.empty(n_views, a, b).uniform_(-bound, bound)
            bias = torch.empty(n_views, 1, b).uniform_(-bound, bound)
            if k == n_layers - 1:  # zero correction at the start of phase 2
                w.zero_()
                bias.zero_()
            self.weights.append(nn.Parameter(w))
            self.biases.append(nn.Parameter(bias))

    @timed("mlp")
    def _mlp(self, x: torch.Tensor, views: torch.Tensor | None = None) -> torch.Tensor:
        """``[k, m, D] -> [k, m, D]``: row block j through branch ``views[j]`` (``views`` None: all n
        branches, block j through branch j)."""
        last = len(self.weights) - 1
        for k, (w, b) in enumerate(zip(self.weights, self.biases)):
            if views is not None:
                w, b = w.index_select(0, views), b.index_select(0, views)
            x = torch.baddbmm(b, x, w)
            if k < last:
                x = torch.relu(x)
        return x

    def forward_all(self, features: torch.Tensor) -> torch.Tensor:
        """Every branch on every sample: ``[S, D] -> [S, n_views, D]``."""
        x = features.unsqueeze(0).expand(self.n_views, -1, -1)
        return (x + self._mlp(x)).transpose(0, 1)

    def forward_own(self, features: torch.Tensor, views: torch.Tensor) -> torch.Tensor:
        """Only the branch of each sample's own view: ``[S, D], views [S] in [0, n) -> [S, D]``, as one
        batched matmul over the samples grouped by view into a padded ``[k, max_count, D]`` block, one
        block per view that has samples (a render of one view runs one branch, not n). Each sample's row
        in the block is found once; the features go in and the outputs come out by row copies."""
        if features.shape[0] == 0:
            return features
        order = torch.argsort(views)
        sorted_views = views[order]
        counts = torch.bincount(sorted_views, minlength=self.n_views)
        present = None
        if not bool((counts > 0).all()):  # compact the views that have samples into blocks 0..k-1
            present = counts.nonzero().squeeze(-1)
            sorted_views = (torch.cumsum(counts > 0, 0) - 1)[sorted_views]
            counts = counts.index_select(0, present)
        starts = torch.cumsum(counts, 0) - counts
        width = int(counts.max())
        slot = torch.arange(views.shape[0], device=views.device) - starts[sorted_views]
        row = torch.empty_like(order).index_copy_(0, order, sorted_views * width + slot)
        dim = features.shape[-1]
        padded = features.new_zeros(counts.shape[0] * width, dim).index_copy(0, row, features)
        out = self._mlp(padded.view(counts.shape[0], width, dim), present).view(-1, dim).index_select(0, row)
        return features + out
