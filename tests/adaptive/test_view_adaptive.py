"""The view-adaptive wrapper on both backbones: phases, gradients, learning rates, canonical path,
checkpoints and the consistent-scene skip."""

import json

import pytest
import torch
from conftest import tiny_config

from va_plugin.adaptive.field import BRANCHES, FUSION, PRETRAIN, ViewAdaptiveField, ViewAdaptiveFieldConfig
from va_plugin.adaptive.phases import phase_at
from va_plugin.analysis.consistency import RESIDUALS_FILE
from va_plugin.errors import ConfigError
from va_plugin.rays import RayBundle

METHODS = ["va-neus", "va-ngp"]
FORCE = {"pipeline.model.field.skip_consistent_scenes": "false"}
PAPER_LR = {"pipeline.model.field.shared_lr_scale": "0.1"}  # the paper's factor: a drop the tests can see


def _trainer(method, scene, out, steps=9, **overrides):
    return tiny_config(method, scene, out, steps=steps, **{**FORCE, **overrides}).setup()


def _run_step(trainer):
    trainer._run_callbacks("before_step")
    trainer._step()
    trainer.step += 1


def test_phase_boundaries_are_fractions_of_the_budget():
    assert [phase_at(s, 9, 1 / 3, 1 / 3) for s in range(9)] == [1, 1, 1, 2, 2, 2, 3, 3, 3]
    assert [phase_at(s, 4, 0.0, 0.0) for s in range(4)] == [3, 3, 3, 3]
    assert [phase_at(s, 4, 0.5, 0.5) for s in range(4)] == [1, 1, 2, 2]


@pytest.mark.parametrize("method", METHODS)
def test_each_phase_trains_the_intended_parameters_at_the_intended_rates(method, tiny_scene, tmp_path):
    trainer = _trainer(method, tiny_scene, tmp_path / "run", **PAPER_LR)
    field = trainer.model.field
    assert isinstance(field, ViewAdaptiveField) and field.num_views == 4 and field.config.shared_lr_scale == 0.1
    shared = {id(p) for p in field.base.parameters()}
    branch = {id(p) for p in field.branches.parameters()}
    fusion = {id(p) for p in field.attention.parameters()}

    def with_grad(ids):
        return {id(p) for p in trainer.model.parameters() if id(p) in ids and p.grad is not None}

    for step in range(9):
        _run_step(trainer)
        phase = field.current_phase
        assert phase == (PRETRAIN, BRANCHES, FUSION)[step // 3]
        assert with_grad(shared), f"step {step}: the shared field got no gradient"
        assert (with_grad(branch) == branch) == (phase >= BRANCHES), f"step {step}, phase {phase}: branches"
        assert (with_grad(fusion) == fusion) == (phase >= FUSION), f"step {step}, phase {phase}: attention"
        if phase >= FUSION:  # the regularizers are on
            assert trainer.model.config.field.entropy_weight > 0
        factor = trainer.config.scheduler.factor(step, trainer.config.max_steps)
        lrs = {g["name"]: g["lr"] for g in trainer.optimizer.param_groups}
        base_lr = {name: trainer.config.optimizers[name].lr * factor for name in lrs}
        shared_scale = 1.0 if phase == PRETRAIN else field.config.shared_lr_scale
        assert lrs["fields"] == pytest.approx(base_lr["fields"] * shared_scale)
        assert lrs["adaptive"] == pytest.approx(base_lr["adaptive"])
    assert all(torch.isfinite(p).all() for p in trainer.model.parameters())
    events = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert [e["phase"] for e in events if "event" in e] == [BRANCHES, FUSION]


@pytest.mark.parametrize("method", METHODS)
def test_canonical_path_is_deterministic_and_ignores_the_view(method, tiny_scene, tmp_path):
    trainer = _trainer(method, tiny_scene, tmp_path / "run", steps=3,
                       **{"pipeline.model.field.pretrain_fraction": 0.0, "pipeline.model.field.branch_fraction": 0.0})
    for _ in range(3):
        _run_step(trainer)
    field, model = trainer.model.field, trainer.model
    with torch.no_grad():  # views now differ: make the branches visibly different
        for w in field.branches.weights:
            w.add_(torch.randn_like(w) * 0.3)
    model.eval()
    dm = trainer.pipeline.datamanager
    rows, cols = torch.meshgrid(torch.arange(0, 24, 3), torch.arange(0, 24, 3), indexing="ij")
    rows, cols = rows.reshape(-1), cols.reshape(-1)
    origins, directions = dm.cameras.generate_rays(torch.zeros_like(rows), rows, cols)
    renders = {}
    for label, index in (("novel", -1), ("view0", 0), ("view2", 2)):
        rays = RayBundle(origins, directions, torch.full_like(rows, index))
        renders[label] = model.render_rays(rays, keys=("rgb",))["rgb"]
    again = model.render_rays(RayBundle(origins, directions, torch.full_like(rows, -1)), keys=("rgb",))["rgb"]
    assert torch.equal(renders["novel"], again)
    assert not torch.allclose(renders["view0"], renders["view2"]), "branches should change a view's render"
    # the canonical color of a point does not depend on which camera index a caller passes for "novel"
    points = torch.rand(64, 3) - 0.5
    normals = torch.nn.functional.normalize(torch.randn(64, 3), dim=-1)
    colors = model.surface_color(points, normals)
    torch.testing.assert_close(colors, model.surface_color(points, normals))


def test_sample_culling_matches_the_full_adaptive_path(tiny_scene, tmp_path):
    trainer = _trainer("va-neus", tiny_scene, tmp_path / "run", steps=2,
                       **{"pipeline.model.field.pretrain_fraction": 0.0, "pipeline.model.field.branch_fraction": 0.0})
    _run_step(trainer)
    field = trainer.model.field
    with torch.no_grad():
        for w in list(field.branches.weights) + [field.attention.out.weight]:
            w.add_(torch.randn_like(w) * 0.3)
    d = field.feature_dim
    positions = torch.rand(2, 5, 3) - 0.5
    normals = torch.nn.functional.normalize(torch.randn(2, 5, 3), dim=-1)
    directions = -normals
    _, geo = field.geometry(positions)
    views = torch.tensor([[0, 0, 0, 0, 0], [-1, -1, -1, -1, -1]])
    weights = torch.tensor([[0.0, 0.5, 1e-5, 0.3, 0.2], [0.9, 0.0, 0.0, 0.05, 0.05]])
    field.eval()
    full = field.color(positions, directions, normals, geo, views)["rgb"]
    culled = field.color(positions, directions, normals, geo, views, weights=weights)["rgb"]
    plain = field.decode_color(field.color_features(positions, directions, normals, geo))
    heavy = weights > field.config.min_sample_weight
    torch.testing.assert_close(culled[heavy], full[heavy])
    torch.testing.assert_close(culled[~heavy], plain[~heavy])
    assert not torch.allclose(full[heavy], plain[heavy]) and d > 0


@pytest.mark.parametrize("backbone", ["neus", "ngp"])
def test_phase_one_trains_exactly_what_the_plain_backbone_trains(backbone, tiny_scene, tmp_path):
    """The adaptive modules initialise from their own random stream: with or without fusion, phase 1 of
    the wrapped method leaves the shared field bit-for-bit where the plain method's training leaves it."""
    plain = tiny_config(backbone, tiny_scene, tmp_path / "plain", steps=3).setup()
    plain.train()
    expected = dict(plain.model.field.state_dict().items())
    for fusion in ("true", "false"):
        wrapped = _trainer(f"va-{backbone}", tiny_scene, tmp_path / f"va-{fusion}", steps=3,
                           **{"pipeline.model.field.pretrain_fraction": 1.0,
                              "pipeline.model.field.branch_fraction": 0.0,
                              "pipeline.model.field.fusion": fusion,
                              "pipeline.model.field.diagnostics_scale": 0})
        wrapped.train()
        got = wrapped.model.field.base.state_dict()
        assert got.keys() == expected.keys()
        for key, value in expected.items():
            assert torch.equal(got[key], value), (fusion, key)


@pytest.mark.parametrize("method", METHODS)
def test_phase_survives_a_checkpoint(method, tiny_scene, tmp_path):
    trainer = _trainer(method, tiny_scene, tmp_path / "run", steps=6, checkpoint_every=3, **PAPER_LR)
    trainer.train()
    assert trainer.model.field.current_phase == FUSION
    again = _trainer(method, tiny_scene, tmp_path / "run", steps=6, checkpoint_every=3, **PAPER_LR)
    assert again.model.field.current_phase == PRETRAIN
    assert again.resume() and again.model.field.current_phase == FUSION
    assert again.lr_multipliers["fields"] == pytest.approx(0.1)


def test_phases_follow_schedule_steps_not_the_budget(tiny_scene, tmp_path):
    """With ``schedule_steps=6`` a 12-step run switches phases at thirds of 6 steps and stays in phase 3."""
    trainer = _trainer("va-neus", tiny_scene, tmp_path / "run", steps=12, schedule_steps=6)
    phases = []
    for _ in range(12):
        _run_step(trainer)
        phases.append(trainer.model.field.current_phase)
    assert phases == [PRETRAIN] * 2 + [BRANCHES] * 2 + [FUSION] * 8


def test_a_consistent_scene_skips_the_adaptive_phases(tiny_scene, tmp_path):
    # a huge threshold: whatever the color casts, the scene counts as consistent (the per-view residuals
    # are recorded but do not vote)
    trainer = tiny_config("va-neus", tiny_scene, tmp_path / "run", steps=3,
                          **{"pipeline.model.field.consistent_color_cast": 1000.0}).setup()
    trainer.train()
    field = trainer.model.field
    assert field.current_phase == PRETRAIN and bool(field.skipped)
    assert all(p.grad is None for p in field.branches.parameters())
    record = json.loads((tmp_path / "run" / RESIDUALS_FILE).read_text())
    assert record["consistent"] and len(record["views"]) == 4 and "psnr" in record["views"][0]
    assert "color_cast" in record  # None here: on the tiny scene no surface point is seen by two views
    assert trainer.lr_multipliers["fields"] == 1.0


def test_a_color_cast_alone_turns_the_adaptive_phases_on(tiny_scene, tmp_path, monkeypatch):
    """Silhouettes say consistent; a view whose fitted gains are 5% apart across channels on a mid-grey
    surface (a shift of 0.025, above the 0.012 threshold) makes the scene inconsistent, and the record
    says why."""
    import numpy as np

    from va_plugin.analysis import consistency as phases
    from va_plugin.analysis.consistency import ColorCast

    def fake_cast(model, cameras, images, masks, resolution):
        return ColorCast(np.array([[1.0, 1.0, 1.0], [1.05, 1.0, 0.95], [1.0, 1.0, 1.0], [1.0, 1.0, 1.0]]), 100, 0.0,
                          np.full((4, 3), 0.5))

    monkeypatch.setattr(phases, "color_cast", fake_cast)
    monkeypatch.setattr(phases, "input_silhouette_support", lambda datamanager: None)
    trainer = tiny_config("va-neus", tiny_scene, tmp_path / "run", steps=3).setup()
    trainer.train()
    assert trainer.model.field.current_phase == FUSION and not bool(trainer.model.field.skipped)
    record = json.loads((tmp_path / "run" / RESIDUALS_FILE).read_text())
    assert not record["consistent"]
    assert record["color_cast"]["consistent"] is False and record["color_cast"]["threshold"] == 0.012
    assert abs(record["color_cast"]["worst_shift"] - 0.5 * 0.0496) < 1e-3


@pytest.mark.parametrize("options,match", [
    ({"branches": False, "fusion": True}, "fusion needs"),
    ({"pretrain_fraction": 0.8, "branch_fraction": 0.5}, "sum to at most 1"),
    ({"attention_dim": 10, "attention_heads": 4}, "multiple"),
    ({"min_sample_weight": -1.0}, ">= 0"),
    ({"consistent_color_cast": -0.1}, ">= 0"),
])
def test_bad_options_are_refused_with_a_message(options, match):
    with pytest.raises(ConfigError, match=match):
        ViewAdaptiveFieldConfig(**options).validate()


@pytest.mark.parametrize("switches", [{"fusion": "false"}, {"branches": "false", "fusion": "false"},
                                      {"entropy_weight": 0.0, "consistency_weight": 0.0}])
def test_ablation_switches_train(switches, tiny_scene, tmp_path):
    overrides = {f"pipeline.model.field.{k}": v for k, v in switches.items()}
    trainer = _trainer("va-neus", tiny_scene, tmp_path / "run", steps=6, **overrides)
    record = trainer.train()
    field = trainer.model.field
    assert (field.attention is None) == (switches.get("fusion") == "false")
    assert (field.branches is None) == (switches.get("branches") == "false")
    assert ("loss_entropy" in record) == (field.attention is not None and field.config.entropy_weight > 0)
    assert all(torch.isfinite(p).all() for p in trainer.model.parameters())


def _heaviest_reference(weights, rays, k):
    """Plain loop: per ray, the k largest weights (ties to the earlier sample)."""
    chosen = [False] * len(weights)
    for ray in set(rays.tolist()):
        members = [i for i in range(len(weights)) if int(rays[i]) == ray]
        members.sort(key=lambda i: (-float(weights[i]), i))
        for i in members[:k]:
            chosen[i] = True
    return torch.tensor(chosen)


@pytest.mark.parametrize("k", [1, 2, 5])
def test_heaviest_per_ray_matches_a_plain_loop(k):
    from va_plugin.adaptive.field import heaviest_per_ray

    gen = torch.Generator().manual_seed(k)
    for _ in range(5):
        rays = torch.randint(0, 7, (60,), generator=gen)  # any order, rays of any length (some empty)
        weights = torch.rand(60, generator=gen).round(decimals=1)  # ties
        assert torch.equal(heaviest_per_ray(weights, rays, k), _heaviest_reference(weights, rays, k))
    # hand-computed: ray 3 has weights .1 .7 .2, ray 0 has .5 .5
    weights = torch.tensor([0.1, 0.5, 0.7, 0.5, 0.2])
    rays = torch.tensor([3, 0, 3, 0, 3])
    assert heaviest_per_ray(weights, rays, 1).tolist() == [False, True, True, False, False]
    assert heaviest_per_ray(weights, rays, 2).tolist() == [False, True, True, True, True]
    assert heaviest_per_ray(weights[:0], rays[:0], 2).numel() == 0


def test_fused_samples_per_ray_fuses_each_rays_heaviest_and_gives_the_rest_their_own_branch(tiny_scene, tmp_path):
    trainer = _trainer("va-neus", tiny_scene, tmp_path / "run", steps=2,
                       **{"pipeline.model.field.pretrain_fraction": 0.0, "pipeline.model.field.branch_fraction": 0.0})
    _run_step(trainer)
    field = trainer.model.field
    assert field.current_phase == FUSION
    with torch.no_grad():
        for w in list(field.branches.weights) + [field.attention.out.weight]:
            w.add_(torch.randn_like(w) * 0.3)
    positions = torch.rand(3, 4, 3) - 0.5
    normals = torch.nn.functional.normalize(torch.randn(3, 4, 3), dim=-1)
    _, geo = field.geometry(positions)
    views = torch.tensor([[0] * 4, [2] * 4, [3] * 4])
    rays = torch.arange(3)[:, None].expand(3, 4)
    weights = torch.tensor([[0.1, 0.6, 0.2, 1e-5], [0.3, 0.3, 0.0, 0.2], [0.05, 0.01, 0.02, 0.9]])
    args = (positions, -normals, normals, geo, views)
    field.train()
    field.config.fused_samples_per_ray = 0
    full = field.color(*args, weights=weights, ray_indices=rays)
    field.config.fused_samples_per_ray = 1
    part = field.color(*args, weights=weights, ray_indices=rays)
    fused = torch.tensor([[0, 1, 0, 0], [1, 0, 0, 0], [0, 0, 0, 1]], dtype=torch.bool)  # top-1 (tie: earlier)
    visible = weights > field.config.min_sample_weight
    shared = field.color_features(positions, -normals, normals, geo)
    own = field.decode_color(field.branches.forward_own(shared.reshape(-1, shared.shape[-1]),
                                                        views.reshape(-1))).reshape(3, 4, 3)
    torch.testing.assert_close(part["rgb"][fused], full["rgb"][fused])
    torch.testing.assert_close(part["rgb"][visible & ~fused], own[visible & ~fused])
    torch.testing.assert_close(part["rgb"][~visible], field.decode_color(shared)[~visible])
    assert not torch.allclose(part["rgb"][visible & ~fused], full["rgb"][visible & ~fused])
    assert torch.equal(part["va_evaluated"].bool(), fused)
    assert field.fused_share == pytest.approx(3 / 12) and field.adaptive_share == pytest.approx(10 / 12)
    # the regularizers average over the fused samples only, by their rendering weights
    losses = field.extra_losses({**part, "weights": weights})
    w = weights[fused]
    expected = field.config.entropy_weight * (part["va_entropy"][fused] * w).sum() / w.sum()
    torch.testing.assert_close(losses["entropy"], expected)
    # phase 2: every visible sample takes its branch, none is fused
    field.set_phase(BRANCHES)
    field.color(*args, weights=weights, ray_indices=rays)
    assert field.adaptive_share == pytest.approx(10 / 12) and field.fused_share == 0.0
    field.set_phase(FUSION)
    # outside training (diagnostics, renders of a training view) a training view's ray renders as it
    # trained: fusing every visible sample would be off what the attention learned
    field.eval()
    torch.testing.assert_close(field.color(*args, weights=weights, ray_indices=rays)["rgb"], part["rgb"])
    assert "va_entropy" not in field.color(*args, weights=weights, ray_indices=rays)


def test_fused_samples_per_ray_must_not_be_negative():
    with pytest.raises(ConfigError, match="fused_samples_per_ray"):
        ViewAdaptiveFieldConfig(fused_samples_per_ray=-1).validate()


def test_the_consistency_check_renders_a_fixed_pixel_budget_over_all_views(tiny_scene, tmp_path):
    from va_plugin.analysis.consistency import view_residuals

    trainer = _trainer("va-ngp", tiny_scene, tmp_path / "run", steps=1)
    model, dm = trainer.pipeline.model, trainer.pipeline.datamanager
    sizes = []
    render = model.render_rays
    model.render_rays = lambda rays, **kw: sizes.append(len(rays)) or render(rays, **kw)
    # with masks: foreground pixels only, spread evenly, the budget shared out over the views
    counts = [int((dm.masks[v, ..., 0] > 0.5).sum()) for v in range(4)]
    assert min(counts) > 0 and max(counts) < 24 * 24
    every = view_residuals(trainer.pipeline, foreground_pixels=10 ** 6)
    assert sizes == counts and all(r["psnr"] == r["psnr_foreground"] for r in every)
    sizes.clear()
    some = view_residuals(trainer.pipeline, foreground_pixels=80)  # 20 a view
    assert sizes == [min(20, c) for c in counts]
    assert all(abs(a["psnr_foreground"] - b["psnr_foreground"]) < 3.0 for a, b in zip(some, every))
    # without masks: an even stride over the whole image
    dm.masks = None
    sizes.clear()
    full = view_residuals(trainer.pipeline)  # 24 x 24 px: every pixel of the 4 views
    assert sizes == [24 * 24] * 4 and len(full) == 4
    sizes.clear()
    budget = view_residuals(trainer.pipeline, total_pixels=200)  # 50 a view: a stride of 4, 6 x 6 pixels
    assert sizes == [36] * 4 and all(r["psnr"] > 0 and "psnr_foreground" not in r for r in budget)


@pytest.mark.parametrize("base", ["neus", "ngp"])
def test_the_wrapper_passes_only_named_queries_to_its_base(base, tiny_scene, tmp_path):
    field = _trainer(f"va-{base}", tiny_scene, tmp_path / "run", steps=1).model.field
    for name in ViewAdaptiveField.BASE_PASSTHROUGH:
        assert hasattr(field, name) == hasattr(field.base, name), name
    assert hasattr(field.base, "encoding") and not hasattr(field, "encoding")  # no accidental passthrough
    with pytest.raises(AttributeError):
        _ = field.no_such_attribute


def test_the_regularizers_leave_the_shared_field_alone(tiny_scene, tmp_path):
    """L_entropy and L_consistency train the branches and the attention only (their gradient on the shared
    field can dissolve the surface at phase 3's start); the color loss still trains the shared field."""
    trainer = _trainer("va-neus", tiny_scene, tmp_path / "run")
    model, field = trainer.model, trainer.model.field
    for _ in range(6):
        _run_step(trainer)
    field.set_phase(FUSION)
    with torch.no_grad():  # branches that disagree, as after phase 2, so the consistency term is not zero
        for p in field.branches.parameters():
            p.add_(0.05 * torch.randn_like(p))
    ray_bundle, batch = trainer.pipeline.datamanager.next_train(6)
    losses = model.get_loss_dict(model.get_outputs(ray_bundle), batch)
    assert losses["consistency"] > 0
    shared = list(field.base.parameters())
    adaptive = list(field.branches.parameters()) + list(field.attention.parameters())
    for name in ("consistency", "entropy"):
        to_shared = torch.autograd.grad(losses[name], shared, retain_graph=True, allow_unused=True)
        to_adaptive = torch.autograd.grad(losses[name], adaptive, retain_graph=True, allow_unused=True)
        reaches = any(g is not None and bool(g.abs().sum() > 0) for g in to_shared)
        assert not reaches, name
        if name == "consistency":
            assert any(g is not None and bool(g.abs().sum() > 0) for g in to_adaptive)
    # the color loss still trains the shared field through the same fused samples
    to_shared = torch.autograd.grad(losses["rgb"], shared, retain_graph=True, allow_unused=True)
    assert any(g is not None and bool(g.abs().sum() > 0) for g in to_shared)


@pytest.mark.parametrize("method", ["va-neus", "va-ngp"])
def test_the_shared_color_loss_renders_the_shared_path_of_the_training_rays(method, tiny_scene, tmp_path):
    """``shared_color_weight``: in phases 2-3 the shared path's render of the same training rays (f_shared
    decoded, what novel views use) meets the inputs too. Phase 1 has no such term (its color already is
    the shared one); off, the loss is the paper's. The term equals the model's color loss on a render of
    the batch with the branches switched off, times its weight."""
    weight = 0.5
    trainer = _trainer(method, tiny_scene, tmp_path / "run", **{"pipeline.model.field.shared_color_weight": weight})
    model, field = trainer.model, trainer.model.field
    ray_bundle, batch = trainer.pipeline.datamanager.next_train(6)
    assert "shared_rgb" not in model.get_loss_dict(model.get_outputs(ray_bundle), batch)  # phase 1
    for phase in (BRANCHES, FUSION):
        field.set_phase(phase)
        with torch.no_grad():  # branches that disagree, as after phase 2
            for p in field.branches.parameters():
                p.add_(0.05 * torch.randn_like(p))
        torch.manual_seed(0)
        outputs = model.get_outputs(ray_bundle)
        losses = model.get_loss_dict(outputs, batch)
        assert "shared_rgb" in losses and not torch.allclose(outputs["rgb_shared"], outputs["rgb"])
        field.set_phase(PRETRAIN)  # the backbone's own render of the same rays
        torch.manual_seed(0)
        plain = model.get_outputs(ray_bundle)["rgb"]
        field.set_phase(phase)
        assert torch.allclose(outputs["rgb_shared"], plain, atol=1e-5)
        expected = weight * model.color_loss(plain, batch["rgb"])
        assert torch.allclose(losses["shared_rgb"], expected, atol=1e-6)
        shared = list(field.base.parameters())
        grads = torch.autograd.grad(losses["shared_rgb"], shared, allow_unused=True)
        assert any(g is not None and bool(g.abs().sum() > 0) for g in grads)
    off = _trainer(method, tiny_scene, tmp_path / "off", **{"pipeline.model.field.shared_color_weight": 0})
    off.model.field.set_phase(FUSION)
    assert "shared_rgb" not in off.model.get_loss_dict(off.model.get_outputs(ray_bundle), batch)


def test_the_regularizers_gradient_equals_a_second_pass_on_detached_features():
    """The fused tokens and attention serve the color and the regularizers with one forward; the gradient
    is the one of the two-pass formulation (the color's pass on f_shared, the regularizers' on f_shared
    detached) bit for bit, and only the color's reaches f_shared."""
    from va_plugin.adaptive.field import _ParametersOnly, own_tokens
    from va_plugin.adaptive.losses import attention_entropy, feature_consistency

    torch.manual_seed(3)
    field = ViewAdaptiveFieldConfig(branch_width=16, attention_dim=16).setup(num_train_views=5)
    with torch.no_grad():
        for p in (*field.branches.parameters(), *field.attention.parameters()):
            p.normal_(0.0, 0.3)
    params = (*field.branches.parameters(), *field.attention.parameters())
    features = torch.randn(40, field.feature_dim)
    views = torch.randint(0, 5, (40,))
    cotangent = torch.randn(40, field.feature_dim)

    def loss(color_tokens, color_alpha, reg_tokens, reg_alpha):
        color = (own_tokens(color_tokens, views) * cotangent).sum()
        return color + attention_entropy(reg_alpha).sum() + feature_consistency(reg_tokens).sum()

    grads = []
    for one_pass in (True, False):
        field.zero_grad(set_to_none=True)
        flat = features.clone().requires_grad_(True)
        tokens, alpha = field.attention(field.branches.forward_all(flat))
        if one_pass:
            reg_tokens, reg_alpha = _ParametersOnly.apply(tokens, alpha, *params)
        else:
            reg_tokens, reg_alpha = field.attention(field.branches.forward_all(flat.detach()))
        loss(tokens, alpha, reg_tokens, reg_alpha).backward()
        grads.append([flat.grad] + [p.grad for p in params])
    for fast, plain in zip(*grads):
        assert torch.equal(fast, plain)
    # the regularizers alone send nothing to f_shared
    flat = features.clone().requires_grad_(True)
    tokens, alpha = field.attention(field.branches.forward_all(flat))
    reg_tokens, reg_alpha = _ParametersOnly.apply(tokens, alpha, *params)
    (attention_entropy(reg_alpha).sum() + feature_consistency(reg_tokens).sum()).backward()
    assert flat.grad is None or not bool(flat.grad.any())
    assert any(bool(p.grad.abs().sum() > 0) for p in params)


def test_the_regularizers_pass_with_frozen_branches_trains_the_attention_alone():
    """Parameters that do not require a gradient get none, and the others still get theirs."""
    from va_plugin.adaptive.field import _ParametersOnly
    from va_plugin.adaptive.losses import feature_consistency

    torch.manual_seed(4)
    field = ViewAdaptiveFieldConfig(branch_width=8, attention_dim=8).setup(num_train_views=3)
    with torch.no_grad():  # branches that disagree, and an output projection that counts
        for p in (*field.branches.parameters(), field.attention.out.weight):
            p.normal_(0.0, 0.3)
    for p in field.branches.parameters():
        p.requires_grad_(False)
    params = (*field.branches.parameters(), *field.attention.parameters())
    tokens, alpha = field.attention(field.branches.forward_all(torch.randn(6, field.feature_dim)))
    reg_tokens, _ = _ParametersOnly.apply(tokens, alpha, *params)
    feature_consistency(reg_tokens).sum().backward()
    assert all(p.grad is None for p in field.branches.parameters())
    assert field.attention.out.weight.grad is not None and bool(field.attention.out.weight.grad.abs().sum() > 0)
