"""The ``va-neus`` method: NeuS with the paper's view-adaptive renderer wrapped around its field.

The branches and the attention are sized to the hash-grid field's 64-wide colour feature f_shared
(2 layers x 64, attention width 64) instead of the paper's 3 x 128 (sized to its 4 x 256 network),
which on the hash backbone made a phase-2 step much dearer than a backbone step.

In phases 2-3 the shared path's render of the training rays meets the inputs too
(``shared_colour_weight=1``), so that the shared path, which the mesh and novel views come from, keeps
fitting the training views. `va-ngp` keeps the field's default (0: the paper's loss)."""

from __future__ import annotations

from method_configs.adaptive import adaptive_method
from method_configs.neus import neus

va_neus = adaptive_method(
    neus, "va-neus", "view-adaptive NeuS: per-view branches + self-attention fusion, three training phases",
    branch_width=64, branch_layers=2, attention_dim=64, shared_colour_weight=1.0)
