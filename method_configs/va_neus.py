"""The ``va-neus`` method: NeuS with the paper's view-adaptive renderer wrapped around its field."""

from __future__ import annotations

from method_configs.adaptive import adaptive_method
from method_configs.neus import neus

va_neus = adaptive_method(
    neus, "va-neus", "view-adaptive NeuS: per-view branches + self-attention fusion, three training phases")
