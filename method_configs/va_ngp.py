"""The ``va-ngp`` method: the hash-grid ``ngp`` backbone with the paper's view-adaptive renderer."""

from __future__ import annotations

from method_configs.adaptive import adaptive_method
from method_configs.ngp import ngp

va_ngp = adaptive_method(
    ngp, "va-ngp", "view-adaptive InstantNGP: per-view branches + self-attention fusion, three training phases")
