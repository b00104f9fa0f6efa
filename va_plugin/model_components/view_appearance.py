"""Per-view appearance correction: a learned colour transform of each training view's renders.

Generated views disagree in colour as a whole: one comes out a little warmer, darker or more
saturated than the next (real SyncDreamer and Zero123++ outputs do, and the benchmark scenes' level-2
"appearance" error draws a gain and an offset per channel). With one shared colour, every such view
pulls the shared colour its own way, and the longer a run fits the inputs, the more of that tint it
bakes into the texture in the places only that view sees. Here the object's colour in view i's renders
is ``A_i c + b_i`` (a 3 x 3 matrix and an offset, per view), while novel views, the mesh colours and the
frozen conditioning view use ``c`` as the shared field renders it. Only the object is corrected: the
background keeps its colour (the generators' backgrounds are keyed out, not tinted).

Because the transform is linear and a ray's colour is a weighted sum of its samples' colours, correcting
the rendered ray is exact: ``sum_k w_k (A c_k + b) = A (rgb - (1 - acc) bg) + acc b``, with ``acc = sum_k w_k``.

A quadratic penalty holds ``A_i`` near the identity and ``b_i`` near zero; each entry's change is
clamped, so that a diverging run cannot invert a view's colours.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Tuple, Type

import torch

from va_plugin.config import InstantiateConfig
from va_plugin.errors import ConfigError
from va_plugin.model_components.per_view import PerViewCorrection

APPEARANCE_MODES = ("off", "gain", "affine")
MAX_CHANGE = 0.5
"""Largest change of any matrix entry or offset (colours are in [0, 1]); real generator tints are a
few percent."""


@dataclass
class ViewAppearanceConfig(InstantiateConfig):
    """Per-view colour correction of the training views' renders."""

    _target: Type = field(default_factory=lambda: ViewAppearance)
    mode: str = "off"
    """"off", "gain" (a gain and an offset per channel: 6 numbers per view) or "affine" (a 3 x 3
    colour matrix and an offset: 12 numbers per view, which also covers hue shifts)."""
    frozen_views: Tuple[int, ...] = (0,)
    """Training views whose colour stays as rendered (the generator's conditioning view): they pin the
    shared colour, which would otherwise be free to take any tint as a whole."""
    penalty_weight: float = 1e-2
    """Weight of the mean squared change (matrix from the identity, offset from zero) in the loss."""


class ViewAppearance(PerViewCorrection):
    """The learned corrections ``[num_views, 12]`` (the matrix's change from the identity, row-major,
    then the offset), zero at the start."""

    def __init__(self, config: ViewAppearanceConfig, num_views: int) -> None:
        if config.mode not in APPEARANCE_MODES:
            raise ConfigError(f"view_appearance.mode must be one of {', '.join(APPEARANCE_MODES)}, "
                              f"got {config.mode!r}")
        if config.penalty_weight < 0:
            raise ConfigError(f"view_appearance.penalty_weight must be >= 0, got {config.penalty_weight}")
        super().__init__(num_views, 12, config.frozen_views, config.penalty_weight)
        self.config = config
        if config.mode == "gain":  # only the matrix's diagonal (entries 0, 4, 8) and the offset
            self.trained[:, [i for i in range(9) if i not in (0, 4, 8)]] = 0.0

    def _delta(self) -> torch.Tensor:
        """The changes ``[V, 12]`` as applied: frozen entries zero, each clamped to +-MAX_CHANGE."""
        return (self.correction * self.trained).clamp(-MAX_CHANGE, MAX_CHANGE)

    @torch.no_grad()
    def max_change(self) -> float:
        """The largest change of any applied entry (0 for the identity)."""
        return float(self._delta().abs().max())

    def transforms(self) -> Tuple[torch.Tensor, torch.Tensor]:
        """Colour matrices ``[V, 3, 3]`` and offsets ``[V, 3]`` as applied (frozen views: identity, zero)."""
        delta = self._delta()
        eye = torch.eye(3, dtype=delta.dtype, device=delta.device)
        return eye + delta[:, :9].reshape(-1, 3, 3), delta[:, 9:]

    def apply(self, rgb: torch.Tensor, accumulation: torch.Tensor, background: torch.Tensor,
              camera_indices: torch.Tensor) -> torch.Tensor:
        """Rendered colours ``[n, 3]`` (composited on ``background``) with their view's correction of the
        object's part; ``accumulation [n, 1]`` is each ray's opacity. Rays of novel views (index -1) and
        of unknown views are returned as they are."""
        matrices, offsets = self.transforms()
        known, safe = self.view_index(camera_indices)
        behind = (1.0 - accumulation).clamp_min(0.0) * background
        foreground = rgb - behind
        corrected = torch.einsum("nij,nj->ni", matrices[safe], foreground) + accumulation * offsets[safe] + behind
        return torch.where(known[:, None], corrected, rgb)

    @torch.no_grad()
    def summary(self) -> Dict[str, object]:
        """Per view the colour matrix and offset, and the largest change of any entry."""
        matrices, offsets = self.transforms()
        change = self._delta().abs()
        per_view = change[: self.num_views].max(-1).values.tolist() if self.num_views else []
        return {"mode": self.config.mode,
                "matrix": [[[round(v, 4) for v in row] for row in m] for m in matrices[: self.num_views].tolist()],
                "offset": [[round(v, 4) for v in o] for o in offsets[: self.num_views].tolist()],
                "largest_change": [round(v, 5) for v in per_view],
                "max_change": round(max(per_view, default=0.0), 5)}
