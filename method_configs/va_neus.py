"""The ``va-neus`` method: NeuS with the paper's view-adaptive renderer wrapped around its field.

The branches and the attention are sized to the hash-grid field's 64-wide f_shared (2 layers x 64,
attention width 64; the paper's 3 x 128 suits its 4 x 256 network). ``shared_color_weight=1`` keeps
the shared path, which the mesh and novel views come from, fitting the training views in phases 2-3."""

from __future__ import annotations

from method_configs.adaptive import adaptive_method
from method_configs.neus import neus

va_neus = adaptive_method(
    neus, "va-neus", "view-adaptive NeuS: per-view branches + self-attention fusion, three training phases",
    branch_width=64, branch_layers=2, attention_dim=64, shared_color_weight=1.0)
