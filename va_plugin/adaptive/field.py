"""``ViewAdaptiveField``: the paper's view-adaptive renderer as a wrapper around any base field.

The wrapper sits between the base field's ``color_features`` (f_shared) and ``decode_color``:

    f_shared --(branch i)--> f_i --(self-attention over i = 1..n)--> f_fused,i --decode--> RGB

Training view i renders with f_fused,i; novel views, evaluation and mesh colors with f_shared (the
*canonical* feature). Geometry is the base field's. A phase flag (1 pre-training, 2 branches,
3 fusion) is set by a trainer callback (``va_plugin.adaptive.phases``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import nn

from va_plugin.adaptive.attention import ViewAttention
from va_plugin.adaptive.branches import ViewBranches
from va_plugin.adaptive.losses import attention_entropy, feature_consistency, weighted_mean
from va_plugin.adaptive.phases import BRANCHES, FUSION, PRETRAIN, diagnostics_callback, phase_callback
from va_plugin.errors import ConfigError
from va_plugin.fields.base import Field, FieldConfig
from va_plugin.fields.sdf_field import SDFFieldConfig

ADAPTIVE_SEED_OFFSET = 7919
"""Added to the run's seed for the stream that initialises the branches and the attention."""


@dataclass
class ViewAdaptiveFieldConfig(FieldConfig):
    """Per-view branches + self-attention fusion around a base field (the paper's Sec. 3)."""

    _target: type = field(default_factory=lambda: ViewAdaptiveField)
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
    pretrain_fraction: float = 1.0 / 3.0
    """Share of the step budget spent in phase 1, global pre-training (the paper: 100k of 300k)."""
    branch_fraction: float = 1.0 / 3.0
    """Share of the step budget in phase 2 (branches without fusion); phase 3 gets the rest."""
    shared_lr_scale: float = 1.0
    """Learning-rate factor of the shared field in phases 2 and 3 (the paper: 0.1)."""
    min_sample_weight: float = 1e-3
    """Samples whose rendering weight is at most this skip the branches and the attention and keep the
    shared color (0: every sample takes the adaptive path)."""
    shared_color_weight: float = 0.0
    """Weight of a second color loss in phases 2-3: the shared path's render of the training rays against
    the inputs. 0: the paper's loss alone."""
    fused_samples_per_ray: int = 1
    """While fusion trains, only the k heaviest visible samples of each training ray are fused; its other
    visible samples take their own view's branch (0: every visible sample is fused)."""
    skip_consistent_scenes: bool = True
    """After pre-training, test whether the inputs agree (silhouette support and color cast); when they
    do, stay in phase 1 (the adaptive phases are skipped)."""
    consistent_color_cast: float = 0.012
    """Threshold of the color-cast test: the largest chromatic shift between a view and view 0 on the
    shared surface, in color units (``ColorCast.worst_shift``); 0 turns the test off."""
    consistency_test: str = "va_plugin.analysis.consistency:decide_skip"
    """With ``skip_consistent_scenes``: the test that decides, as ``module:function`` taking the field, the
    callback's attributes and the step, and returning True to skip the adaptive phases."""
    diagnostics_writer: str = "va_plugin.analysis.diagnostics:write_diagnostics"
    """What writes the pictures after the last step, as ``module:function`` (pipeline, run folder, scale)."""
    diagnostics_scale: float = 0.5
    """At the end of training, write the attention heat map and the per-view inconsistency maps to the
    run folder, rendered at this fraction of the input resolution (0: don't)."""

    def setup_for_scene(self, scene):
        """The wrapper for a scene: it needs the number of training views (one branch each)."""
        return self.setup(num_train_views=scene.num_train_views)

    def validate(self, prefix: str = "") -> None:
        if self.fusion and not self.branches:
            raise ConfigError("fusion needs the per-view branches (set branches=true or fusion=false)")
        if not (self.pretrain_fraction >= 0.0 and self.branch_fraction >= 0.0
                and self.pretrain_fraction + self.branch_fraction <= 1.0):
            raise ConfigError("pretrain_fraction and branch_fraction must be >= 0 and sum to at most 1, got "
                              f"{self.pretrain_fraction} and {self.branch_fraction}")
        if min(self.entropy_weight, self.consistency_weight, self.shared_lr_scale, self.min_sample_weight,
               self.diagnostics_scale, self.fused_samples_per_ray, self.consistent_color_cast) < 0:
            raise ConfigError("entropy_weight, consistency_weight, shared_lr_scale, min_sample_weight, "
                              "diagnostics_scale, fused_samples_per_ray and consistent_color_cast must be >= 0")
        if self.branch_layers < 1 or self.branch_width < 1 or self.attention_heads < 1:
            raise ConfigError("branch_layers, branch_width and attention_heads must be positive")
        if self.attention_dim % self.attention_heads:
            raise ConfigError(f"attention_dim {self.attention_dim} must be a multiple of "
                              f"attention_heads {self.attention_heads}")


class ViewAdaptiveField(Field):
    """A base field plus n per-view branches and a self-attention fusion module."""

    has_view_branches = True

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
        # The adaptive modules draw from a stream of their own, so the global stream is the wrapped
        # method's: phase 1 trains exactly what the plain backbone trains.
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed((torch.initial_seed() + ADAPTIVE_SEED_OFFSET) % 2 ** 63)
            self.branches = ViewBranches(num_train_views, d, config.branch_width, config.branch_layers) \
                if config.branches else None
            self.attention = ViewAttention(d, config.attention_dim, config.attention_heads) \
                if config.fusion else None
        # persistent so a loaded checkpoint renders in the phase it finished in
        self.also_canonical = False  # set by the diagnostics: color() also returns ``rgb_canonical`` (see there)
        self.register_buffer("phase", torch.tensor(PRETRAIN))
        self.register_buffer("skipped", torch.tensor(False))
        self._phase = PRETRAIN  # host copy of the buffer: no device sync per color query
        self.register_load_state_dict_post_hook(lambda module, _: module._refresh_phase())
        self.register_buffer("attention_sum", torch.zeros(num_train_views, num_train_views))
        self.register_buffer("attention_mass", torch.zeros(()))
        self.adaptive_share = 0.0  # share of the last training batch's samples that took the branch/attention path
        self.fused_share = 0.0  # share of the last training batch's samples that took the fused path (phase 3)

    # -- phases (set by the trainer's callback) ---------------------------------------------------
    def update_step(self, step: int, schedule_steps: int) -> None:
        self.base.update_step(step, schedule_steps)

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

    @property
    def analytic_sdf_gradient(self) -> bool:
        return self.base.analytic_sdf_gradient

    @property
    def bound(self) -> float | None:
        return self.base.bound

    def geometry_and_gradient(self, positions: torch.Tensor):
        return self.base.geometry_and_gradient(positions)

    BASE_PASSTHROUGH = frozenset({"sdf", "density"})
    """The base field's backbone-specific queries the wrapper passes on (when the base field has them)."""

    def __getattr__(self, name: str):
        try:
            return super().__getattr__(name)  # parameters, buffers and submodules
        except AttributeError:
            if name in ViewAdaptiveField.BASE_PASSTHROUGH:
                return getattr(super().__getattr__("base"), name)
            raise

    def color(self, positions, directions, normals, geo_features, camera_indices=None,
              weights=None, ray_indices=None) -> dict[str, torch.Tensor]:
        """RGB ``[..., 3]`` of samples: training rays (``camera_indices >= 0``) use their view's
        f_fused,i, novel-view rays (-1) f_shared. While fusion trains, the per-sample regularizers
        ``va_entropy`` and ``va_consistency`` (``[...]``) come along, with the attention ``va_attention``
        ``[A, n, n]`` and its samples' weights ``va_attention_weights`` ``[A]`` for :meth:`extra_losses`.

        Given rendering ``weights``, only samples heavier than ``min_sample_weight`` take the adaptive
        path; with ``ray_indices``, ``fused_samples_per_ray`` fuses only each ray's heaviest samples.
        With ``also_canonical`` set, ``rgb_canonical`` (the same samples' canonical color) comes along."""
        shared = self.base.color_features(positions, directions, normals, geo_features)
        mode = self._mode()
        if not mode.branches:
            return with_canonical({"rgb": self.base.decode_color(shared)}, mode)
        lead, d = shared.shape[:-1], shared.shape[-1]
        flat = shared.reshape(-1, d)
        views = flat_views(camera_indices, flat.shape[0], flat.device)
        if bool((views < 0).all()):
            return with_canonical({"rgb": self.base.decode_color(shared)}, mode)
        if weights is None or mode.min_sample_weight <= 0:
            out = self._every_sample(flat, views, mode)
        else:
            flat_weights = weights.reshape(-1)
            rays = None if ray_indices is None else ray_indices.reshape(-1).to(flat.device)
            routes = route_samples(flat_weights, views, rays, mode)
            out = self._routed(flat, views, flat_weights, routes, mode)
            if mode.training:
                self.adaptive_share, self.fused_share = routes.shares(mode)
        out = {k: v if k.startswith("va_attention") else v.reshape(lead + v.shape[1:]) for k, v in out.items()}
        return with_canonical(out, mode)

    def _mode(self) -> ColorMode:
        """The switches of this query, read once."""
        cfg = self.config
        return ColorMode(branches=self.branches_active(), fusion=self.fusion_active(), training=self.training,
                         also_canonical=self.also_canonical, min_sample_weight=cfg.min_sample_weight,
                         fused_samples_per_ray=cfg.fused_samples_per_ray if self.fusion_active() else 0,
                         shared_color=self.training and cfg.shared_color_weight > 0)

    def _every_sample(self, flat: torch.Tensor, views: torch.Tensor, mode: ColorMode) -> dict[str, torch.Tensor]:
        """Every sample ``[S, D]`` takes the adaptive path (no rendering weights, or no culling)."""
        out = self._adaptive(flat, views, None, mode)
        if mode.also_canonical or mode.shared_color:
            shared_rgb = self.base.decode_color(flat)
            if mode.also_canonical:
                out["rgb_canonical"] = shared_rgb
            if mode.shared_color:
                out["rgb_shared"] = shared_rgb
        return out

    def _routed(self, flat: torch.Tensor, views: torch.Tensor, weights: torch.Tensor, routes: SampleRoutes,
                mode: ColorMode) -> dict[str, torch.Tensor]:
        """The shared color everywhere, overwritten where ``routes`` send a sample down the adaptive path
        (``routes.adaptive``) or through its own view's branch alone (``routes.own_only``); ``flat [S, F]``:
        the samples' shared features, ``views [S]`` their rays' training views, ``weights [S]`` their
        rendering weights."""
        index = routes.adaptive
        sub = self._adaptive(flat.index_select(0, index), views[index], weights[index], mode)
        base_rgb = self.base.decode_color(flat)
        rgb = base_rgb.index_copy(0, index, sub.pop("rgb"))
        if routes.own_only is not None:
            own = routes.own_only
            own_rgb = self.base.decode_color(self.branches.forward_own(flat.index_select(0, own), views[own]))
            rgb = rgb.index_copy(0, own, own_rgb)
        out = {"rgb": rgb}
        if mode.shared_color:
            out["rgb_shared"] = base_rgb
        if mode.also_canonical:
            out["rgb_canonical"] = base_rgb  # the shared color is the canonical one
        for key in ("va_attention", "va_attention_weights"):
            if key in sub:
                out[key] = sub.pop(key)
        if sub:  # per-sample regularizers: 0 where not evaluated, averaged over where they were
            out["va_evaluated"] = routes.evaluated.to(flat.dtype)
        for key, value in sub.items():
            out[key] = value.new_zeros(flat.shape[0]).index_copy(0, index, value)
        return out

    def _adaptive(self, flat: torch.Tensor, views: torch.Tensor, weights: torch.Tensor | None,
                  mode: ColorMode) -> dict[str, torch.Tensor]:
        """The branch (+ fusion) path on flat features ``[S, D]`` with views ``[S]`` (-1: canonical) and
        their rendering weights ``[S]`` (None: unknown): ``rgb [S, 3]``, and as :meth:`color` says."""
        novel = views < 0
        cfg = self.config
        if not mode.fusion and not bool(novel.any()):
            # branches alone: each sample needs only its own view's branch
            return {"rgb": self.base.decode_color(self.branches.forward_own(flat, views))}
        tokens = self.branches.forward_all(flat)  # [S, n, D]
        alpha = None
        if mode.fusion:
            tokens, alpha = self.attention(tokens)
        own = own_tokens(tokens, views)
        feature = torch.where(novel[:, None], flat, own)
        out = {"rgb": self.base.decode_color(feature)}
        if mode.fusion and mode.training:
            if cfg.entropy_weight > 0 or cfg.consistency_weight > 0:
                # the regularizers' gradient must not reach f_shared (it can dissolve the surface)
                params = (*self.branches.parameters(), *self.attention.parameters())
                reg_tokens, reg_alpha = _ParametersOnly.apply(tokens, alpha, *params)
                if cfg.entropy_weight > 0:
                    out["va_entropy"] = attention_entropy(reg_alpha)
                if cfg.consistency_weight > 0:
                    out["va_consistency"] = feature_consistency(reg_tokens)
            out["va_attention"] = alpha.detach().mean(1)  # [S, n, n], over the heads
            if weights is not None:
                out["va_attention_weights"] = weights.detach()
        return out

    # -- losses and diagnostics -------------------------------------------------------------------
    def extra_losses(self, outputs: dict[str, torch.Tensor], batch: dict[str, torch.Tensor] | None = None,
                     color_loss: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] | None = None
                     ) -> dict[str, torch.Tensor]:
        """The weighted regularizers of eq. 14, averaged over samples by their rendering weights; the
        attention of the batch (``va_attention``) joins the running attention matrix. With
        ``shared_color_weight`` and the model's ``color_loss``, the shared path's render of the batch
        (``rgb_shared``) against the batch's colors, as the loss ``shared_rgb``."""
        cfg = self.config
        weights = outputs.get("weights")
        if weights is not None and "va_evaluated" in outputs:  # only where the regularizers were evaluated
            weights = weights.detach() * outputs["va_evaluated"]
        losses: dict[str, torch.Tensor] = {}
        if "va_entropy" in outputs:
            losses["entropy"] = cfg.entropy_weight * weighted_mean(outputs["va_entropy"], weights)
        if "va_consistency" in outputs:
            losses["consistency"] = cfg.consistency_weight * weighted_mean(outputs["va_consistency"], weights)
        if "va_attention" in outputs:
            self._accumulate_attention(outputs["va_attention"], outputs.get("va_attention_weights"), weights)
        if "rgb_shared" in outputs and batch is not None and color_loss is not None:
            losses["shared_rgb"] = cfg.shared_color_weight * color_loss(outputs["rgb_shared"], batch["rgb"])
        return losses

    @torch.no_grad()
    def _accumulate_attention(self, alpha: torch.Tensor, sample_weights: torch.Tensor | None,
                              weights: torch.Tensor | None) -> None:
        """Running sum of the attention ``alpha [A, n, n]`` over training samples, weighted by rendering
        weight (``sample_weights [A]``, else the batch's ``weights`` when they match)."""
        if sample_weights is None and weights is not None and weights.numel() == alpha.shape[0]:
            sample_weights = weights.detach().reshape(-1)
        w = torch.ones_like(alpha[:, 0, 0]) if sample_weights is None else sample_weights.to(alpha.dtype)
        self.attention_sum += (alpha * w[:, None, None]).sum(0)
        self.attention_mass += w.sum()

    def attention_matrix(self) -> torch.Tensor | None:
        """The ``[n_views, n_views]`` attention matrix averaged over surface samples (row i: how view i's
        feature draws on each view j), or None before fusion has trained."""
        if float(self.attention_mass) <= 0:
            return None
        return (self.attention_sum / self.attention_mass).cpu()

    def param_groups(self) -> dict[str, list[nn.Parameter]]:
        groups = {"fields": list(self.base.parameters())}
        adaptive: list[nn.Parameter] = []
        for module in (self.branches, self.attention):
            if module is not None:
                adaptive.extend(module.parameters())
        groups["adaptive"] = adaptive
        return groups

    def training_callbacks(self) -> list:
        callbacks = [phase_callback(self)]
        if self.config.diagnostics_scale > 0:
            callbacks.append(diagnostics_callback(self))
        return callbacks

    def diagnostics(self) -> dict[str, float]:
        out = {"phase": float(self.current_phase)}
        if self.branches_active():
            out["adaptive_share"] = round(self.adaptive_share, 4)
        if self.fusion_active():
            out["fused_share"] = round(self.fused_share, 4)
        return out


def own_tokens(tokens: torch.Tensor, views: torch.Tensor) -> torch.Tensor:
    """Each sample's token of its own view: ``tokens [S, n, D], views [S] -> [S, D]`` (view -1: token 0)."""
    d = tokens.shape[-1]
    return tokens.gather(1, views.clamp_min(0)[:, None, None].expand(-1, 1, d)).squeeze(1)


class _ParametersOnly(torch.autograd.Function):
    """The identity on the fused tokens ``[S, n, D]`` and the attention ``[S, H, n, n]``, whose backward
    sends their gradient to ``params`` (the branches' and the attention's) and not further back: the
    gradient the same pass on f_shared detached would give, without a second forward."""

    @staticmethod
    def forward(ctx, tokens: torch.Tensor, alpha: torch.Tensor, *params: torch.Tensor):
        ctx.set_materialize_grads(False)
        ctx.graph, ctx.params = (tokens, alpha), params
        return tokens.detach(), alpha.detach()

    @staticmethod
    def backward(ctx, grad_tokens, grad_alpha):
        used = [(t, g) for t, g in zip(ctx.graph, (grad_tokens, grad_alpha)) if g is not None and t.requires_grad]
        grads: list[torch.Tensor | None] = [None] * len(ctx.params)
        wanted = [k for k, p in enumerate(ctx.params) if p.requires_grad]
        if used and wanted:
            outputs, cotangents = zip(*used)
            # the forward's graph is kept: the colors' gradient runs through it after this
            found = torch.autograd.grad(outputs, [ctx.params[k] for k in wanted], cotangents, retain_graph=True,
                                        allow_unused=True)
            for k, grad in zip(wanted, found):
                grads[k] = grad
        return None, None, *grads


@dataclass(frozen=True)
class ColorMode:
    """The switches of one color query, read once from the field's phase, config and flags."""

    branches: bool  # the per-view branches are on (phase 2 or 3)
    fusion: bool  # the attention fusion is on (phase 3)
    training: bool  # the regularizers and the attention record are wanted
    also_canonical: bool  # ``rgb_canonical`` is wanted beside ``rgb`` (diagnostics)
    min_sample_weight: float  # samples at most this heavy keep the shared color
    fused_samples_per_ray: int  # while fusion is on (0: every visible sample; always 0 without fusion)
    shared_color: bool = False  # ``rgb_shared`` (the shared path's color) is wanted


@dataclass(frozen=True)
class SampleRoutes:
    """Which flat samples take which color path (the others keep the shared color)."""

    adaptive: torch.Tensor  # [A] indices of the samples on the adaptive path (fused, in the fusion phase)
    own_only: torch.Tensor | None  # [B] visible samples on their own view's branch alone, or None
    evaluated: torch.Tensor  # bool [S]: ``adaptive`` as a mask (where the regularizers are evaluated)

    def shares(self, mode: ColorMode) -> tuple:
        """(adaptive share, fused share) of the ``S`` samples: what :meth:`ViewAdaptiveField.diagnostics` logs."""
        total = max(self.evaluated.shape[0], 1)
        share = self.adaptive.numel() / total
        fused = share if mode.fusion else 0.0
        return (share if self.own_only is None else share + self.own_only.numel() / total), fused


def flat_views(camera_indices: torch.Tensor | None, n_samples: int, device: torch.device) -> torch.Tensor:
    """The view of each sample ``[S]`` (long; -1: a novel view) from ``camera_indices [...]`` (None: all novel)."""
    if camera_indices is None:
        return torch.full((n_samples,), -1, dtype=torch.long, device=device)
    return camera_indices.reshape(-1).to(device)


def route_samples(weights: torch.Tensor, views: torch.Tensor, ray_indices: torch.Tensor | None,
                  mode: ColorMode) -> SampleRoutes:
    """Where each sample ``[S]`` goes: training-view samples heavier than ``min_sample_weight`` take the
    adaptive path; with ``fused_samples_per_ray`` k > 0 and known rays, only each ray's k heaviest are
    fused and its other visible samples take their own branch."""
    active = (weights > mode.min_sample_weight) & (views >= 0)
    own_only = None
    if mode.fused_samples_per_ray > 0 and ray_indices is not None:
        heavy = heaviest_per_ray(weights, ray_indices, mode.fused_samples_per_ray)
        own_only = active & ~heavy & (views >= 0)
        active &= ~own_only
    return SampleRoutes(adaptive=active.nonzero().squeeze(-1),
                        own_only=None if own_only is None else own_only.nonzero().squeeze(-1), evaluated=active)


def with_canonical(out: dict[str, torch.Tensor], mode: ColorMode) -> dict[str, torch.Tensor]:
    """``out`` with ``rgb_canonical`` (= ``rgb``) when the query wants it and the path gave none."""
    if mode.also_canonical and "rgb_canonical" not in out:
        out["rgb_canonical"] = out["rgb"]
    return out


def heaviest_per_ray(weights: torch.Tensor, ray_indices: torch.Tensor, k: int) -> torch.Tensor:
    """Which samples (in any order) are among the ``k`` heaviest of their ray: ``weights [S], ray_indices
    [S] -> bool [S]``; ties go to the earlier sample."""
    if weights.numel() == 0:
        return torch.zeros_like(weights, dtype=torch.bool)
    if k == 1:
        return _heaviest_one_per_ray(weights, ray_indices)
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


def _heaviest_one_per_ray(weights: torch.Tensor, ray_indices: torch.Tensor) -> torch.Tensor:
    """:func:`heaviest_per_ray` for ``k = 1`` by two scatter reductions: each ray's largest weight, then
    the first sample of the ray that carries it; ``weights [S], ray_indices [S] -> bool [S]``."""
    rays = ray_indices.long()
    n_rays = int(rays.max()) + 1
    top = weights.new_full((n_rays,), -torch.inf).scatter_reduce(0, rays, weights, "amax")
    position = torch.arange(weights.numel(), device=weights.device)
    candidate = weights == top[rays]
    first = torch.full((n_rays,), weights.numel(), dtype=torch.long, device=weights.device)
    first = first.scatter_reduce(0, rays[candidate], position[candidate], "amin")
    chosen = torch.zeros_like(weights, dtype=torch.bool)
    chosen[first[first < weights.numel()]] = True
    return chosen
