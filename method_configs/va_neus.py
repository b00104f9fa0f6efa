"""The ``va-neus`` method: NeuS with the paper's view-adaptive renderer wrapped around its field.

The branches and the attention are sized to the hash-grid field's 64-wide colour feature f_shared
(2 layers x 64, attention width 64) instead of the paper's 3 x 128 (sized to its 4 x 256 network): on
the hash backbone the paper's size made a phase-2 step 1.7x a backbone step (benchmarks/RESULTS.md,
"Branches sized to the hash backbone").

Since 2026-11-26 the shared path's render of the training rays meets the inputs too in phases 2-3
(``shared_colour_weight=1``): on all six real generator outputs the shared path (what the mesh and
novel views come from) then fits the training views 0.27-1.06 dB better than `neus`'s, where without it
it was below on 5/6; a tie on GSO-10 level 2 (benchmarks/RESULTS.md, "The shared-path colour loss on
every real output"). `va-ngp` keeps the field's default (0: the paper's loss; not measured there)."""

from __future__ import annotations

from method_configs.adaptive import adaptive_method
from method_configs.neus import neus

va_neus = adaptive_method(
    neus, "va-neus", "view-adaptive NeuS: per-view branches + self-attention fusion, three training phases",
    branch_width=64, branch_layers=2, attention_dim=64, shared_colour_weight=1.0)
