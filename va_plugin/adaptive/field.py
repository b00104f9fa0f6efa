"""``ViewAdaptiveField``: the paper's view-adaptive renderer as a wrapper around any base field.

The base field's colour path is split into f_shared (``color_features``) and ``decode_color``; the
wrapper sits between the halves:

    f_shared --(branch i)--> f_i --(self-attention over i = 1..n)--> f_fused,i --decode--> RGB

A ray from training view i renders with f_fused,i. Novel views, evaluation and mesh colours render
with the *canonical* feature: f_shared itself (``canonical="shared"``, the default: as cheap as the
base field) or the mean over views of f_fused,i (``canonical="mean"``, DESIGN.md's first choice; see
benchmarks/RESULTS.md for why it is no longer the default). Geometry is the base field's, shared by all
views, so one surface exists to extract.

The field knows nothing about training steps: it holds a phase flag (1 pre-training, 2 branches,
3 fusion) that a trainer callback (``va_plugin.adaptive.phases``) sets.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Optional, Type

import torch
from torch import nn

from va_plugin.adaptive.attention import ViewAttention
from va_plugin.adaptive.branches import ViewBranches
from va_plugin.adaptive.losses import attention_entropy, feature_consistency, weighted_mean
from va_plugin.errors import ConfigError
from va_plugin.fields.base import Field, FieldConfig
from va_plugin.fields.sdf_field import SDFFieldConfig

PRETRAIN, BRANCHES, FUSION = 1, 2, 3
PHASE_NAMES = {PRETRAIN: "global pre-training", BRANCHES: "view-adaptive branches", FUSION: "self-attention fusion"}


ADAPTIVE_SEED_OFFSET = 7919
"""Added to the run's seed for the stream that initialises the branches and the attention."""


@dataclass
class ViewAdaptiveFieldConfig(FieldConfig):
    """Per-view branches + self-attention fusion around a base field (the paper's Sec. 3)."""

    _target: Type = field(default_factory=lambda: ViewAdaptiveField)
    base: FieldConfig = field(default_factory=SDFFieldConfig)
    """The wrapped field (an SDF field for NeuS, a density field for NGP)."""
    branches: bool = True
    """Per-view branches (off: the base field alone, the ablation's baseline)."""
    fusion: bool = True
    """Self-attention fusion across the branch features (needs branches)."""
    entropy_weight: float = 0.01
    """lambda_entropy of eq. 14 (the paper's 0.01); 0 turns L_entropy off."""
    consistency_weight: float = 0.1
    """lambda_consistency of eq. 14 (the paper's 0.1); 0 turns L_consistency off."""
    branch_width: int = 128
    """Hidden width of a branch (the paper: 128)."""
    branch_layers: int = 3
    """Linear layers per branch (the paper: 3)."""
    attention_dim: int = 128
    """Width of the query/key/value projections, split over the heads."""
    attention_heads: int = 4
    """Attention heads H (the paper: 4)."""
    canonical: str = "shared"
    """Feature for novel views and mesh colours: "shared" (f_shared: as cheap as the base field) or "mean"
    (mean over views of f_fused,i, which needs fused_samples_per_ray=0)."""
    pretrain_fraction: float = 1.0 / 3.0
    """Share of the step budget spent in phase 1, global pre-training (the paper: 100k of 300k)."""
    branch_fraction: float = 1.0 / 3.0
    """Share of the step budget in phase 2 (branches without fusion); phase 3 gets the rest."""
    shared_lr_scale: float = 1.0
    """Learning-rate factor of the shared field in phases 2 and 3. The paper drops it to 1/10 after a
    converged 100k-step pre-training; at our budgets phase 1 has not converged and 0.1 freezes an
    unfinished field (measured, benchmarks/RESULTS.md: -0.3 to -1.0 dB held-out PSNR and +9% to +32% CD
    against the backbone, where 1.0 ties it). 0.1 helps only past convergence (`ngp`, 3000 steps:
    +0.22 dB), and there the drop alone, without branches, does as much."""
    min_sample_weight: float = 1e-3
    """Samples whose rendering weight is at most this skip the branches and the attention and keep the
    shared colour (0: every sample takes the adaptive path). Such a sample changes its pixel by at most
    this fraction of the colour difference, and a ray's weights mostly sit on a few samples."""
    fused_samples_per_ray: int = 1
    """While fusion trains, only the k heaviest visible samples of each training ray take the fused path
    (every view's branch plus the attention); its other visible samples use their own view's branch,
    the phase-2 path that fusion starts from (0: every visible sample is fused). Phase 3's cost grows
    with n views x fused samples, and a ray's colour sits on a few samples near the surface. With k > 0
    the attention and the consistency loss see only those samples, so canonical="mean" (which fuses
    every sample) is refused for training."""
    skip_consistent_scenes: bool = True
    """After pre-training, measure how well the shared field explains each input; when every view is
    explained to within ``consistent_residual_db``, stay in phase 1 (the adaptive phases are skipped)."""
    consistent_residual_db: float = 1.0
    """Threshold of that test: the largest per-view PSNR shortfall below the best view, in dB."""
    diagnostics_scale: float = 0.5
    """At the end of training, write the attention heat map and the per-view inconsistency maps to the
    run folder, rendered at this fraction of the input resolution (0: don't)."""
    needs_num_views: bool = field(default=True, repr=False)
    """Tells the model to pass the number of training views (not an option)."""

    def validate(self) -> None:
        if self.fusion and not self.branches:
            raise ConfigError("fusion needs the per-view branches (set branches=true or fusion=false)")
        if self.canonical not in ("mean", "shared"):
            raise ConfigError(f"canonical must be 'mean' or 'shared', got {self.canonical!r}")
        if not (0.0 <= self.pretrain_fraction and 0.0 <= self.branch_fraction
                and self.pretrain_fraction + self.branch_fraction <= 1.0):
            raise ConfigError("pretrain_fraction and branch_fraction must be >= 0 and sum to at most 1, got "
                              f"{self.pretrain_fraction} and {self.branch_fraction}")
        if min(self.entropy_weight, self.consistency_weight, self.shared_lr_scale, self.min_sample_weight,
               self.diagnostics_scale, self.fused_samples_per_ray) < 0:
            raise ConfigError("entropy_weight, consistency_weight, shared_lr_scale, min_sample_weight, "
                              "diagnostics_scale and fused_samples_per_ray must be >= 0")
        if self.branch_layers < 1 or self.branch_width < 1 or self.attention_heads < 1:
            raise ConfigError("branch_layers, branch_width and attention_heads must be positive")
        if self.attention_dim % self.attention_heads:
            raise ConfigError(f"attention_dim {self.attention_dim} must be a multiple of "
                              f"attention_heads {self.attention_heads}")


class ViewAdaptiveField(Field):
    """A base field plus n per-view branches and a self-attention fusion module."""

    def __init__(self, config: ViewAdaptiveFieldConfig, num_train_views: int) -> None:
        super().__init__()
        config.validate()
        if num_train_views < 1:
            raise ConfigError("a view-adaptive field needs at least one training view")
        self.config = config
        self.num_views = num_train_views
        self.base = config.base.setup()
        self.geometry_kind = self.base.geometry_kind
        self.feature_dim = self.base.feature_dim
        d = self.feature_dim
        # The adaptive modules draw their initial weights from a stream of their own (derived from the
        # run's seed), so the global random stream (the base field above, then every training batch) is
        # the wrapped method's: phase 1 trains exactly what the plain backbone trains, whichever
        # components are switched on, and paired comparisons see the components' effect, not a reshuffle.
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed((torch.initial_seed() + ADAPTIVE_SEED_OFFSET) % 2 ** 63)
            self.branches = ViewBranches(num_train_views, d, config.branch_width, config.branch_layers) \
                if config.branches else None
            self.attention = ViewAttention(d, config.attention_dim, config.attention_heads) \
                if config.fusion else None
        # persistent so a loaded checkpoint renders in the phase it finished in
        self.also_canonical = False
        """Set by the diagnostics: colour() also returns ``rgb_canonical`` (see there)."""
        self.register_buffer("phase", torch.tensor(PRETRAIN))
        self.register_buffer("skipped", torch.tensor(False))
        self._phase = PRETRAIN  # host copy of the buffer: no device sync per colour query
        self.register_load_state_dict_post_hook(lambda module, _: module._refresh_phase())
        self.register_buffer("attention_sum", torch.zeros(num_train_views, num_train_views))
        self.register_buffer("attention_mass", torch.zeros(()))
        self._last_alpha: Optional[tuple] = None
        self.adaptive_share = 0.0
        """Share of the last training batch's samples that took the branch/attention path."""
        self.fused_share = 0.0
        """Share of the last training batch's samples that took the fused path (phase 3)."""

    # -- phases (set by the trainer's callback) ---------------------------------------------------
    def update_step(self, step: int, max_steps: int) -> None:
        self.base.update_step(step, max_steps)

    def set_phase(self, phase: int) -> None:
        self.phase.fill_(int(phase))
        self._phase = int(phase)

    def _refresh_phase(self) -> None:
        self._phase = int(self.phase)

    @property
    def current_phase(self) -> int:
        return self._phase

    def branches_active(self) -> bool:
        return self.branches is not None and self.current_phase >= BRANCHES

    def fusion_active(self) -> bool:
        return self.attention is not None and self.current_phase >= FUSION

    # -- the Field interface ----------------------------------------------------------------------
    def geometry(self, positions: torch.Tensor):
        return self.base.geometry(positions)

    def color_features(self, positions, directions, normals, geo_features) -> torch.Tensor:
        return self.base.color_features(positions, directions, normals, geo_features)

    def decode_color(self, features: torch.Tensor) -> torch.Tensor:
        return self.base.decode_color(features)

    def __getattr__(self, name: str):
        # backbone-specific queries (sdf(), density(), ...) go to the wrapped field
        try:
            return super().__getattr__(name)
        except AttributeError:
            return getattr(super().__getattr__("base"), name)

    def color(self, positions, directions, normals, geo_features, camera_indices=None,
              weights=None, ray_indices=None) -> Dict[str, torch.Tensor]:
        """RGB ``[..., 3]`` of samples; training rays (``camera_indices >= 0``) use their view's
        f_fused,i, novel-view rays (-1) the canonical feature. While fusion trains, the per-sample
        regularizers ``va_entropy`` and ``va_consistency`` (``[...]``) come along.

        Given the samples' rendering ``weights``, only samples weighing more than
        ``min_sample_weight`` go through the branches and the attention; the others (empty space,
        occluded points: most samples of a ray) keep the shared colour and contribute nothing to the
        regularizers. In the fusion phase, ``ray_indices`` (the ray of each sample) let
        ``fused_samples_per_ray`` fuse only each ray's heaviest samples, in training and when a
        training view is rendered afterwards (diagnostics), so such a render shows what trained.

        With ``also_canonical`` set (the diagnostics do), ``rgb_canonical`` comes along: the canonical
        colour of the same samples, so one render pass gives both a view's own and its canonical image."""
        out = self._color(positions, directions, normals, geo_features, camera_indices, weights, ray_indices)
        if self.also_canonical and "rgb_canonical" not in out:
            out["rgb_canonical"] = out["rgb"]
        return out

    def _color(self, positions, directions, normals, geo_features, camera_indices,
               weights, ray_indices=None) -> Dict[str, torch.Tensor]:
        shared = self.base.color_features(positions, directions, normals, geo_features)
        cfg = self.config
        if not self.branches_active():
            return {"rgb": self.base.decode_color(shared)}
        lead, d = shared.shape[:-1], shared.shape[-1]
        flat = shared.reshape(-1, d)
        if camera_indices is None:
            views = torch.full((flat.shape[0],), -1, dtype=torch.long, device=flat.device)
        else:
            views = camera_indices.reshape(-1).to(flat.device)
        if cfg.canonical == "shared" and bool((views < 0).all()):
            return {"rgb": self.base.decode_color(shared)}
        if weights is None or cfg.min_sample_weight <= 0:
            out = self._adaptive(flat, views, None)
            if self.also_canonical and cfg.canonical == "shared":
                out["rgb_canonical"] = self.base.decode_color(flat)
            return {k: v.reshape(lead + v.shape[1:]) for k, v in out.items()}
        flat_weights = weights.reshape(-1)
        active = flat_weights > cfg.min_sample_weight
        if cfg.canonical == "shared":
            active &= views >= 0
        own_only = None
        if (self.fusion_active() and cfg.fused_samples_per_ray > 0
                and ray_indices is not None):
            heavy = heaviest_per_ray(flat_weights, ray_indices.reshape(-1).to(flat.device),
                                     cfg.fused_samples_per_ray)
            own_only = active & ~heavy & (views >= 0)
            active &= ~own_only
        index = active.nonzero().squeeze(-1)
        if self.training:
            share = index.numel() / max(flat.shape[0], 1)
            self.fused_share = share if self.fusion_active() else 0.0
            self.adaptive_share = share if own_only is None else share + int(own_only.sum()) / max(flat.shape[0], 1)
        sub = self._adaptive(flat[index], views[index], flat_weights[index])
        base_rgb = self.base.decode_color(flat)
        rgb = base_rgb.index_copy(0, index, sub.pop("rgb"))
        if own_only is not None:
            own_index = own_only.nonzero().squeeze(-1)
            own = self.branches.forward_own(flat[own_index], views[own_index])
            rgb = rgb.index_copy(0, own_index, self.base.decode_color(own))
        out = {"rgb": rgb}
        if "rgb_canonical" in sub:
            out["rgb_canonical"] = base_rgb.index_copy(0, index, sub.pop("rgb_canonical"))
        elif self.also_canonical and cfg.canonical == "shared":
            out["rgb_canonical"] = base_rgb  # the shared colour is the canonical one
        if sub:  # per-sample regularizers: 0 where not evaluated, averaged over where they were
            out["va_evaluated"] = active.to(flat.dtype)
        for key, value in sub.items():
            out[key] = value.new_zeros(flat.shape[0]).index_copy(0, index, value)
        return {k: v.reshape(lead + v.shape[1:]) for k, v in out.items()}

    def _adaptive(self, flat: torch.Tensor, views: torch.Tensor,
                  weights: Optional[torch.Tensor]) -> Dict[str, torch.Tensor]:
        """The branch (+ fusion) path on flat features ``[S, D]`` with views ``[S]`` (-1: canonical)."""
        cfg = self.config
        novel = views < 0
        d = flat.shape[-1]
        fusion = self.fusion_active()
        if not fusion and not bool(novel.any()) and not self.also_canonical:
            # branches alone: each sample needs only its own view's branch
            return {"rgb": self.base.decode_color(self.branches.forward_own(flat, views))}
        tokens = self.branches.forward_all(flat)  # [S, n, D]
        alpha = None
        if fusion:
            tokens, alpha = self.attention(tokens)
        own = tokens.gather(1, views.clamp_min(0)[:, None, None].expand(-1, 1, d)).squeeze(1)
        canonical = flat if cfg.canonical == "shared" else tokens.mean(1)
        feature = torch.where(novel[:, None], canonical, own)
        out = {"rgb": self.base.decode_color(feature)}
        if self.also_canonical and cfg.canonical != "shared":
            out["rgb_canonical"] = self.base.decode_color(canonical)
        if fusion and self.training:
            if cfg.entropy_weight > 0:
                out["va_entropy"] = attention_entropy(alpha)
            if cfg.consistency_weight > 0:
                out["va_consistency"] = feature_consistency(tokens)
            self._last_alpha = (alpha.detach().mean(1), None if weights is None else weights.detach())
        return out

    # -- losses and diagnostics -------------------------------------------------------------------
    def extra_losses(self, outputs: Dict[str, torch.Tensor]) -> Dict[str, torch.Tensor]:
        """The weighted regularizers of eq. 14, averaged over samples by their rendering weights."""
        cfg = self.config
        weights = outputs.get("weights")
        if weights is not None and "va_evaluated" in outputs:  # only where the regularizers were evaluated
            weights = weights.detach() * outputs["va_evaluated"]
        losses: Dict[str, torch.Tensor] = {}
        if "va_entropy" in outputs:
            losses["entropy"] = cfg.entropy_weight * weighted_mean(outputs["va_entropy"], weights)
        if "va_consistency" in outputs:
            losses["consistency"] = cfg.consistency_weight * weighted_mean(outputs["va_consistency"], weights)
        self._accumulate_attention(weights)
        return losses

    @torch.no_grad()
    def _accumulate_attention(self, weights: Optional[torch.Tensor]) -> None:
        """Running sum of the attention matrix over training samples, weighted by rendering weight
        (so it reflects samples on the surface, not in empty space)."""
        last, self._last_alpha = self._last_alpha, None
        if last is None:
            return
        alpha, sample_weights = last
        if sample_weights is None and weights is not None and weights.numel() == alpha.shape[0]:
            sample_weights = weights.detach().reshape(-1)
        w = torch.ones_like(alpha[:, 0, 0]) if sample_weights is None else sample_weights.to(alpha.dtype)
        self.attention_sum += (alpha * w[:, None, None]).sum(0)
        self.attention_mass += w.sum()

    def attention_matrix(self) -> Optional[torch.Tensor]:
        """The n x n attention matrix averaged over surface samples (row i: how view i's feature
        draws on each view j), or None before fusion has trained."""
        if float(self.attention_mass) <= 0:
            return None
        return (self.attention_sum / self.attention_mass).cpu()

    def param_groups(self) -> Dict[str, List[nn.Parameter]]:
        groups = {"fields": list(self.base.parameters())}
        adaptive: List[nn.Parameter] = []
        for module in (self.branches, self.attention):
            if module is not None:
                adaptive.extend(module.parameters())
        groups["adaptive"] = adaptive
        return groups

    def training_callbacks(self) -> list:
        from va_plugin.adaptive.phases import diagnostics_callback, phase_callback

        cfg = self.config
        if cfg.canonical == "mean" and cfg.fused_samples_per_ray > 0 and self.attention is not None:
            # checked for training only: a run trained before this option existed still loads
            raise ConfigError(
                "canonical='mean' fuses every visible sample of a novel view, but with fused_samples_per_ray="
                f"{cfg.fused_samples_per_ray} the attention and the consistency loss train only on each ray's "
                "heaviest samples (measured: 3.5 dB lower held-out PSNR on va-neus); set "
                "pipeline.model.field.fused_samples_per_ray=0 with canonical=mean, or keep canonical=shared")
        callbacks = [phase_callback(self)]
        if self.config.diagnostics_scale > 0:
            callbacks.append(diagnostics_callback(self))
        return callbacks

    def diagnostics(self) -> Dict[str, float]:
        out = {"phase": float(self.current_phase)}
        if self.branches_active():
            out["adaptive_share"] = round(self.adaptive_share, 4)
        if self.fusion_active():
            out["fused_share"] = round(self.fused_share, 4)
        return out


def heaviest_per_ray(weights: torch.Tensor, ray_indices: torch.Tensor, k: int) -> torch.Tensor:
    """Which samples are among the ``k`` heaviest of their ray: ``weights [S], ray_indices [S] -> bool [S]``.

    Samples may come in any order and rays with any number of samples; ties go to the earlier sample."""
    if weights.numel() == 0:
        return torch.zeros_like(weights, dtype=torch.bool)
    by_weight = torch.argsort(weights, descending=True, stable=True)
    order = by_weight[torch.argsort(ray_indices[by_weight], stable=True)]  # by ray, heaviest first
    rays = ray_indices[order]
    position = torch.arange(rays.numel(), device=rays.device)
    new_ray = torch.ones_like(rays, dtype=torch.bool)
    new_ray[1:] = rays[1:] != rays[:-1]
    first = torch.cummax(torch.where(new_ray, position, torch.zeros_like(position)), 0).values
    chosen = torch.zeros_like(weights, dtype=torch.bool)
    chosen[order] = (position - first) < k
    return chosen
