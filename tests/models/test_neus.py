import pytest
import torch

from conftest import tiny_config
from va_plugin.model_components.neus import sdf_band


def _trainer(tiny_scene, tmp_path, **overrides):
    torch.manual_seed(0)
    return tiny_config("neus", tiny_scene, tmp_path / "neus", **overrides).setup()


def test_sdf_band_hand_computed():
    edges = torch.tensor([[0.0, 0.1, 0.2, 0.3, 0.4]])
    sdf = torch.tensor([[1.0, 0.9, 0.25, 0.05, 0.6]])
    # lowest SDF a section may reach: min of its ends minus its length = [0.8, 0.15, -0.05, -0.05];
    # inv_s 10 and margin 2 keep the sections whose lowest value is below 0.2
    t = torch.tensor([[0.05, 0.1, 0.15, 0.35, 0.4]])  # 0.1 is in section 1; 0.4 (the last edge) in section 3
    keep = sdf_band(edges, sdf, t, torch.tensor(10.0), margin=2.0)
    assert keep.tolist() == [[False, True, True, True, True]]
    # a wider margin keeps everything; inside (negative SDF) is always kept
    assert sdf_band(edges, sdf, t, torch.tensor(10.0), margin=9.0).all()
    assert sdf_band(edges, -sdf, t, torch.tensor(1e4), margin=2.0).all()


def test_far_sample_skipping_renders_like_every_sample(tiny_scene, tmp_path):
    trainer = _trainer(tiny_scene, tmp_path, **{"pipeline.model.n_samples": 16,
                                                "pipeline.model.skip_far_samples": False})
    model = trainer.model
    with torch.no_grad():
        model.variance.variance.fill_(0.5)  # inv_s = e^5 ~ 148: a band narrow enough to drop samples
    rays, batch = trainer.pipeline.datamanager.next_train(0)
    torch.manual_seed(1)
    dense = model.get_outputs(rays)
    dense_samples = model.samples_per_ray
    model.config.skip_far_samples = True
    torch.manual_seed(1)  # the same jitter
    skipped = model.get_outputs(rays)
    assert model.samples_per_ray < 0.9 * dense_samples
    assert model.samples_per_ray == pytest.approx(skipped["weights"].numel() / len(rays))
    assert skipped["gradients"].shape == (skipped["weights"].numel(), 3)
    # a dropped sample had alpha at NeuS's 1e-5 floor (1e-5 / (Phi + 1e-5)): at most ~30 of them per ray
    for key in ("rgb", "accumulation", "normal"):
        assert torch.allclose(skipped[key], dense[key], atol=5e-4), key
    hit = dense["accumulation"][:, 0] > 0.5  # depth is normalised by the accumulation: compare where it means something
    assert hit.any() and torch.allclose(skipped["depth"][hit], dense["depth"][hit], atol=1e-3)
    loss = sum(model.get_loss_dict(skipped, batch).values())
    loss.backward()
    assert torch.isfinite(loss)
    assert all(p.grad is None or torch.isfinite(p.grad).all() for p in model.parameters())


def test_a_batch_with_every_sample_skipped_renders_background(tiny_scene, tmp_path):
    trainer = _trainer(tiny_scene, tmp_path, **{"pipeline.model.skip_far_samples": True})
    model = trainer.model
    with torch.no_grad():
        model.field.sdf_net.out.bias[0] = 5.0  # far outside everywhere
        model.variance.variance.fill_(0.5)
    rays, batch = trainer.pipeline.datamanager.next_train(0)
    outputs = model.get_outputs(rays)
    assert outputs["weights"].numel() == 0 and model.samples_per_ray == 0
    assert torch.allclose(outputs["rgb"], model.background.expand_as(outputs["rgb"]))
    loss = sum(model.get_loss_dict(outputs, batch).values())
    loss.backward()
    assert torch.isfinite(loss)


def test_training_logs_samples_per_ray(tiny_scene, tmp_path):
    trainer = _trainer(tiny_scene, tmp_path, steps=2)
    record = trainer.train()
    cfg = trainer.model.config
    coarse = cfg.n_samples + 2
    assert 0 < record["samples_per_ray"] <= coarse + cfg.n_importance - 1
    assert coarse <= record["probed_per_ray"] <= coarse + cfg.n_importance // cfg.up_sample_steps


@pytest.mark.parametrize("skip_far_samples", [False, True])
def test_color_gets_each_samples_ray_and_camera_index(skip_far_samples, tiny_scene, tmp_path):
    """The ray index each sample carries (the view-adaptive field ranks samples within a ray by it) must
    be that sample's ray, packed or not."""
    trainer = _trainer(tiny_scene, tmp_path, **{"pipeline.model.skip_far_samples": str(skip_far_samples).lower()})
    model = trainer.model
    calls = []
    color = model.field.color

    def recording_color(positions, directions, normals, geo_features, camera_indices=None, weights=None,
                        ray_indices=None):
        calls.append((positions.detach().clone(), directions, camera_indices, ray_indices))
        return color(positions, directions, normals, geo_features, camera_indices, weights=weights,
                     ray_indices=ray_indices)

    model.field.color = recording_color
    rays, _ = trainer.pipeline.datamanager.next_train(0)
    model.get_outputs(rays)
    positions, directions, camera, ray = calls[-1]
    assert ray.shape == camera.shape == positions.shape[:-1]
    # packed [n_kept] with the band, [n_rays, n_samples] without: the field flattens them row-major
    positions, directions = positions.reshape(-1, 3), directions.reshape(-1, 3)
    camera, ray = camera.reshape(-1), ray.reshape(-1)
    assert bool((ray[1:] >= ray[:-1]).all())
    assert ray.unique().numel() <= len(rays)
    # samples that share a ray index lie on one ray: same direction, same camera, collinear positions
    first = torch.searchsorted(ray, ray)  # index of the first sample of each sample's ray (packed ray by ray)
    assert torch.equal(directions, directions[first]) and torch.equal(camera, camera[first])
    offset = positions - positions[first]
    across = torch.linalg.cross(offset, directions[first], dim=-1).norm(dim=-1)
    assert float(across.max()) < 1e-4


def test_normal_smoothness_hand_computed():
    from va_plugin.model_components.neus import normal_smoothness

    a = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 2.0], [0.0, 0.0, 0.0]])
    b = torch.tensor([[0.0, 3.0, 0.0], [0.0, 0.0, 0.5], [1.0, 0.0, 0.0]])
    # 1 - cos: perpendicular 1, parallel (any lengths) 0, a zero gradient gives a zero normal: 1
    assert float(normal_smoothness(a, b)) == pytest.approx((1.0 + 0.0 + 1.0) / 3)
    empty = torch.zeros(0, 3, requires_grad=True)
    value = normal_smoothness(empty, empty)
    value.backward()
    assert float(value.detach()) == 0.0


def test_smoothness_prior_is_a_finite_loss_that_trains_the_geometry(tiny_scene, tmp_path):
    trainer = _trainer(tiny_scene, tmp_path, **{"pipeline.model.smoothness_weight": 1.0})
    model = trainer.model
    rays, batch = trainer.pipeline.datamanager.next_train(0)
    outputs = model.get_outputs(rays)
    assert outputs["surface_valid"].any()  # the sphere start covers the object's pixels
    loss = model.get_loss_dict(outputs, batch)
    assert 0.0 < float(loss["smoothness"].detach()) < 2.0
    loss["smoothness"].backward()
    grads = [p.grad for p in model.field.encoding.parameters() if p.grad is not None]
    assert grads and all(torch.isfinite(g).all() for g in grads) and any(g.abs().sum() > 0 for g in grads)
    # off by default: no surface points are kept and no term is added
    plain = _trainer(tiny_scene, tmp_path / "plain", **{"pipeline.model.inv_s_floor": 0.0}).model
    out = plain.get_outputs(rays)
    assert "surface_points" not in out and "smoothness" not in plain.get_loss_dict(out, batch)


@pytest.mark.parametrize("key, value", [("smoothness_weight", -1.0), ("smoothness_radius", 0.0),
                                        ("smoothness_points", 0)])
def test_bad_smoothness_options_are_config_errors(key, value, tiny_scene, tmp_path):
    from va_plugin.errors import ConfigError

    with pytest.raises(ConfigError, match=key):
        _trainer(tiny_scene, tmp_path, **{f"pipeline.model.{key}": value})


def test_render_sharpness_scales_inv_s_for_novel_views_only(tiny_scene, tmp_path):
    from va_plugin.rays import RayBundle

    trainer = _trainer(tiny_scene, tmp_path, **{"pipeline.model.render_sharpness": 3.0})
    model = trainer.model
    with torch.no_grad():
        model.variance.variance.fill_(0.4)  # inv_s = e^4
    rays, _ = trainer.pipeline.datamanager.next_train(0)
    novel = RayBundle(rays.origins, rays.directions, torch.full_like(rays.camera_indices, -1))
    model.eval()
    sharp = model.get_outputs(novel)
    as_trained = model.get_outputs(rays)  # training views' own rays: the learned inv_s
    model.config.render_sharpness = 1.0
    plain = model.get_outputs(novel)
    own = model.get_outputs(rays)
    # the reference: the same render with the learned inv_s itself three times larger
    with torch.no_grad():
        model.variance.variance.fill_(0.4 + torch.log(torch.tensor(3.0)).item() / 10.0)
    reference = model.get_outputs(novel)
    for key in ("rgb", "accumulation"):
        assert torch.allclose(sharp[key], reference[key], atol=1e-5), key
        assert torch.equal(as_trained[key], own[key]), key
    # a sharper kernel moves the opacity towards 0 or 1
    gap = lambda out: (out["accumulation"] * (1 - out["accumulation"])).mean()  # noqa: E731
    assert gap(sharp) < gap(plain)
    model.train()
    model.config.render_sharpness = 3.0
    with torch.no_grad():
        model.variance.variance.fill_(0.4)
    torch.manual_seed(2)
    trained = model.get_outputs(novel)
    model.config.render_sharpness = 1.0
    torch.manual_seed(2)
    assert torch.equal(trained["rgb"], model.get_outputs(novel)["rgb"])  # training never sharpens


def test_render_sharpness_must_be_positive(tiny_scene, tmp_path):
    from va_plugin.errors import ConfigError

    with pytest.raises(ConfigError, match="render_sharpness"):
        _trainer(tiny_scene, tmp_path, **{"pipeline.model.render_sharpness": 0.0})


def test_isotropic_rays_meet_a_sphere_in_proportion_to_its_outline():
    from va_plugin.rays import isotropic_rays, near_far_from_sphere

    torch.manual_seed(0)
    rays = isotropic_rays(100_000, 2.0)
    assert torch.allclose(rays.directions.norm(dim=-1), torch.ones(100_000), atol=1e-5)
    assert float(rays.origins.norm(dim=-1).min()) > 2.0 and bool((rays.camera_indices == -1).all())
    # every ray meets the sphere of the disk's radius; a concentric sphere of radius a is met by a fraction
    # (a / radius)^2 of them (its outline over the disk's area), whatever the direction
    assert bool(near_far_from_sphere(rays.origins, rays.directions, 2.0)[2].all())
    hits = near_far_from_sphere(rays.origins, rays.directions, 0.6)[2]
    assert float(hits.float().mean()) == pytest.approx(0.09, abs=0.004)
    # uniform directions: no axis preferred
    assert torch.allclose((rays.directions ** 2).mean(0), torch.full((3,), 1 / 3), atol=0.01)


def test_projected_area_prior_measures_the_outline_and_shrinks_it(tiny_scene, tmp_path):
    trainer = _trainer(tiny_scene, tmp_path, **{"pipeline.model.projected_area_weight": 1.0,
                                                "pipeline.model.projected_area_rays": 4096,
                                                "pipeline.model.projected_area_start": 0.0,
                                                "pipeline.model.cos_anneal_fraction": 0.0})
    model = trainer.model
    with torch.no_grad():
        model.variance.variance.fill_(0.6)  # inv_s = e^6: a sharp outline
    rays, batch = trainer.pipeline.datamanager.next_train(0)
    outputs = model.get_outputs(rays)
    counters = model.samples_per_ray, model.probed_per_ray
    loss = model.get_loss_dict(outputs, batch)["projected_area"]
    assert (model.samples_per_ray, model.probed_per_ray) == counters  # the batch's figures, not the prior's
    # against the share of the same rays on which the SDF, densely sampled, goes below zero
    from va_plugin.rays import isotropic_rays, near_far_from_sphere

    torch.manual_seed(5)
    probe = isotropic_rays(4096, model.scene.scene_radius)
    nears, fars, _ = near_far_from_sphere(probe.origins, probe.directions, model.scene.scene_radius)
    t = nears + (fars - nears) * torch.linspace(0, 1, 400)
    points = probe.origins[:, None] + probe.directions[:, None] * t[..., None]
    outline = float((model.mesh_field(points.reshape(-1, 3)).reshape(t.shape).min(-1).values < 0).float().mean())
    assert 0.1 < outline < 0.9
    assert float(loss.detach()) == pytest.approx(outline, abs=0.03)
    optimizer = torch.optim.Adam(model.field.parameters(), lr=1e-2)
    first = float(loss.detach())
    for _ in range(15):
        optimizer.zero_grad()
        loss = model.get_loss_dict(outputs, batch)["projected_area"]
        loss.backward()
        assert all(torch.isfinite(p.grad).all() for p in model.field.parameters() if p.grad is not None)
        optimizer.step()
    assert float(loss.detach()) < first - 0.01
    # before its start no term is added
    late = _trainer(tiny_scene, tmp_path / "late", **{"pipeline.model.projected_area_weight": 1.0,
                                                     "pipeline.model.projected_area_start": 0.5})
    out = late.model.get_outputs(rays)
    assert "projected_area" not in late.model.get_loss_dict(out, batch)


@pytest.mark.parametrize("key, value", [("projected_area_weight", -0.1), ("projected_area_rays", 0),
                                        ("projected_area_start", 1.5)])
def test_bad_projected_area_options_are_config_errors(key, value, tiny_scene, tmp_path):
    from va_plugin.errors import ConfigError

    with pytest.raises(ConfigError, match=key):
        _trainer(tiny_scene, tmp_path, **{f"pipeline.model.{key}": value})


def test_surface_crossings_hand_computed():
    from va_plugin.model_components.neus import surface_crossings

    torch.manual_seed(0)
    sphere = lambda p: p.norm(dim=-1) - 0.5  # noqa: E731
    two_spheres = lambda p: torch.minimum((p - torch.tensor([-0.5, 0.0, 0.0])).norm(dim=-1),  # noqa: E731
                                          (p - torch.tensor([0.5, 0.0, 0.0])).norm(dim=-1)) - 0.3
    # along x through the centre, through an off-centre chord, and past the sphere by 0.3 (ten spacings)
    origins = torch.tensor([[-2.0, 0.0, 0.0], [-2.0, 0.3, 0.0], [-2.0, 0.8, 0.0]])
    directions = torch.tensor([[1.0, 0.0, 0.0]]).expand(3, 3)
    nears, fars = torch.full((3, 1), 1.0), torch.full((3, 1), 3.0)  # chords from x = -1 to 1, spacing 2 / 64
    assert surface_crossings(sphere, origins, directions, nears, fars, 64).tolist() == pytest.approx(
        [1.0, 1.0, 0.0], abs=0.01)
    # the line through both spheres leaves the surface and enters it again: two; a line of zero length: none
    crossings = surface_crossings(two_spheres, origins, directions, nears, fars, 64)
    assert [float(crossings[0]), float(crossings[2])] == pytest.approx([2.0, 0.0], abs=0.01)
    assert float(surface_crossings(sphere, origins[:1], directions[:1], nears[:1], nears[:1], 8)) == 0.0


def test_surface_crossings_gradient_fills_a_gap_and_leaves_a_convex_inside_alone():
    from va_plugin.model_components.neus import surface_crossings

    torch.manual_seed(0)
    offset = torch.zeros(1, requires_grad=True)  # added to the SDF at the samples: raising it shrinks the shape
    # a line through two touching-but-apart spheres: the gap between them is pushed inside (offset down)
    two_spheres = lambda p: torch.minimum((p - torch.tensor([-0.32, 0.0, 0.0])).norm(dim=-1),  # noqa: E731
                                          (p - torch.tensor([0.32, 0.0, 0.0])).norm(dim=-1)) - 0.3 + offset * (
        p[..., 0].abs() < 0.05)
    origin, direction = torch.tensor([[-2.0, 0.0, 0.0]]), torch.tensor([[1.0, 0.0, 0.0]])
    near, far = torch.full((1, 1), 1.0), torch.full((1, 1), 3.0)
    surface_crossings(two_spheres, origin, direction, near, far, 64).sum().backward()
    assert float(offset.grad) > 0.5  # lowering the SDF in the gap (filling it) lowers the count
    # deep inside a convex body the indicator is saturated: no gradient there
    offset.grad = None
    inner = lambda p: p.norm(dim=-1) - 0.6 + offset * (p.norm(dim=-1) < 0.2)  # noqa: E731
    surface_crossings(inner, origin, direction, near, far, 64).sum().backward()
    assert abs(float(offset.grad)) < 1e-3


def test_crossings_prior_is_a_finite_loss_after_its_start(tiny_scene, tmp_path):
    trainer = _trainer(tiny_scene, tmp_path, **{"pipeline.model.crossings_weight": 1.0,
                                                "pipeline.model.projected_area_start": 0.0})
    model = trainer.model
    rays, batch = trainer.pipeline.datamanager.next_train(0)
    loss = model.get_loss_dict(model.get_outputs(rays), batch)["crossings"]
    assert torch.isfinite(loss) and 0.0 <= float(loss.detach()) <= model.config.crossings_samples / 2
    loss.backward()
    grads = [p.grad for p in model.field.parameters() if p.grad is not None]
    assert grads and all(torch.isfinite(g).all() for g in grads) and any(float(g.abs().max()) > 0 for g in grads)
    late = _trainer(tiny_scene, tmp_path / "late", **{"pipeline.model.crossings_weight": 1.0,
                                                     "pipeline.model.projected_area_start": 0.5})
    assert "crossings" not in late.model.get_loss_dict(late.model.get_outputs(rays), batch)


@pytest.mark.parametrize("key, value", [("crossings_weight", -0.1), ("crossings_samples", 1)])
def test_bad_crossings_options_are_config_errors(key, value, tiny_scene, tmp_path):
    from va_plugin.errors import ConfigError

    with pytest.raises(ConfigError, match=key):
        _trainer(tiny_scene, tmp_path, **{f"pipeline.model.{key}": value})


def test_surface_crossings_band_matches_every_point_with_a_graph():
    from va_plugin.model_components.neus import surface_crossings
    from va_plugin.rays import isotropic_rays, near_far_from_sphere

    centre = torch.tensor([0.1, -0.05, 0.0], requires_grad=True)
    radius = torch.tensor(0.4, requires_grad=True)
    wobble = torch.tensor(0.05, requires_grad=True)

    def sdf(p):  # a sphere with a ripple: lines cross it up to four times
        q = p - centre
        return q.norm(dim=-1) - radius + wobble * torch.sin(12.0 * q[..., 0])

    results = []
    for band in (None, 6.0):
        torch.manual_seed(3)
        rays = isotropic_rays(256, 0.9)
        nears, fars, _ = near_far_from_sphere(rays.origins, rays.directions, 0.9)
        value = surface_crossings(sdf, rays.origins, rays.directions, nears, fars, 64, band=band).mean()
        grads = torch.autograd.grad(value, (centre, radius, wobble))
        results.append((value.detach(), grads))
    (full, full_grads), (banded, banded_grads) = results
    assert float(banded) == pytest.approx(float(full), abs=1e-6)
    for a, b in zip(full_grads, banded_grads):
        assert torch.allclose(a, b, rtol=0.02, atol=1e-3)
    assert float(full_grads[1]) > 0.1  # a larger sphere is crossed by more lines


def test_colour_angle_weight_hand_computed():
    from va_plugin.models.neus import colour_angle_weight

    directions = torch.tensor([[0.0, 0.0, -2.0]] * 4)  # not unit length: normalised inside
    # square on (cos 1), 60 degrees (cos 0.5), facing away (cos < 0), no normal at all (an empty ray)
    normal = torch.tensor([[0.0, 0.0, 0.9], [0.0, 3 ** 0.5 / 2, 0.5], [0.0, 0.0, -1.0], [0.0, 0.0, 0.0]])
    accumulation = torch.tensor([[1.0], [1.0], [0.5], [0.0]])
    weight = colour_angle_weight(normal, accumulation, directions, 2.0)
    assert torch.allclose(weight, torch.tensor([1.0, 0.25, 0.5, 1.0]), atol=1e-6)
    half = colour_angle_weight(normal[1:2], torch.tensor([[0.5]]), directions[:1], 2.0)
    assert torch.allclose(half, torch.tensor([0.5 + 0.5 * 0.25]))


def test_colour_angle_weight_is_the_weighted_mean_of_the_colour_error(tiny_scene, tmp_path):
    trainer = _trainer(tiny_scene, tmp_path, **{"pipeline.model.colour_angle_power": 4.0})
    model = trainer.model
    rays, batch = trainer.pipeline.datamanager.next_train(0)
    outputs = model.get_outputs(rays)
    weight = outputs["colour_weight"]
    assert weight.shape == (len(rays),) and not weight.requires_grad
    assert float(weight.min()) >= 0.0 and float(weight.max()) <= 1.0 + 1e-6
    error = ((outputs["rgb"] - batch["rgb"]) ** 2).mean(-1)
    loss = model.get_loss_dict(outputs, batch)["rgb"]
    assert torch.allclose(loss, (weight * error).sum() / weight.sum(), rtol=1e-5)
    loss.backward()
    assert all(torch.isfinite(p.grad).all() for p in model.field.parameters() if p.grad is not None)
    model.eval()
    assert "colour_weight" not in model.get_outputs(rays)  # evaluation renders carry no training weight


@pytest.mark.parametrize("key, value", [("colour_angle_power", -1.0), ("colour_angle_power", float("nan")),
                                        ("colour_angle_mode", "pixel")])
def test_bad_colour_angle_options_are_config_errors(key, value, tiny_scene, tmp_path):
    from va_plugin.errors import ConfigError

    with pytest.raises(ConfigError, match=key):
        _trainer(tiny_scene, tmp_path, **{f"pipeline.model.{key}": value})


def test_scale_gradient_keeps_the_value_and_scales_the_gradient():
    from va_plugin.model_components.losses import scale_gradient

    x = torch.tensor([1.0, -2.0, 3.0], requires_grad=True)
    y = scale_gradient(x * 2.0, torch.tensor([1.0, 0.5, 0.0]))
    assert torch.equal(y.detach(), torch.tensor([2.0, -4.0, 6.0]))
    y.sum().backward()
    assert torch.allclose(x.grad, torch.tensor([2.0, 1.0, 0.0]))


def test_colour_mode_leaves_the_geometry_gradient_and_scales_the_colour_networks(tiny_scene, tmp_path):
    grads, losses = {}, {}
    for name, extra in (("plain", {}), ("colour", {"pipeline.model.colour_angle_power": 2.0,
                                                  "pipeline.model.colour_angle_mode": "colour"})):
        trainer = _trainer(tiny_scene, tmp_path / name, **extra)
        model = trainer.model
        rays, batch = trainer.pipeline.datamanager.next_train(0)
        outputs = model.get_outputs(rays)
        assert "colour_weight" not in outputs
        losses[name] = model.get_loss_dict(outputs, batch)["rgb"]
        losses[name].backward()
        grads[name] = {k: p.grad.clone() for k, p in model.named_parameters() if p.grad is not None}
    # the same loss; inv_s shapes the opacities only, so its gradient is the same; the colour network's differs
    assert torch.allclose(losses["plain"], losses["colour"])
    assert grads["plain"]["variance.variance"].abs() > 0
    assert torch.allclose(grads["plain"]["variance.variance"], grads["colour"]["variance.variance"], rtol=1e-4)
    colour = [k for k in grads["plain"] if k.startswith("field.color_net")]
    assert colour and not all(torch.allclose(grads["plain"][k], grads["colour"][k], rtol=1e-3) for k in colour)


def test_inv_s_floor_rises_from_its_start_and_lifts_the_learned_value(tiny_scene, tmp_path):
    trainer = _trainer(tiny_scene, tmp_path, **{"pipeline.model.inv_s_floor": 500.0,
                                                "pipeline.model.inv_s_floor_start": 0.5,
                                                "max_steps": 8, "schedule_steps": 8})
    model, steps = trainer.model, trainer.model.scene.max_steps
    assert steps == 8
    assert model.inv_s_floor(0) == 0.0 and model.inv_s_floor(steps // 2) == 0.0
    assert model.inv_s_floor(steps) == pytest.approx(500.0) and model.inv_s_floor(10 * steps) == pytest.approx(500.0)
    assert model.inv_s_floor(6) == pytest.approx(250.0)
    start = float(model.variance.inv_s().detach())
    model.update_step(steps // 2)
    assert float(model.variance.inv_s().detach()) == pytest.approx(start)  # below the start: untouched
    model.update_step(steps)
    assert float(model.variance.inv_s().detach()) == pytest.approx(500.0, rel=1e-4)
    plain = _trainer(tiny_scene, tmp_path / "plain", **{"pipeline.model.inv_s_floor": 0.0})
    plain.model.update_step(steps)
    assert float(plain.model.variance.inv_s().detach()) == pytest.approx(start)


@pytest.mark.parametrize("key, value", [("inv_s_floor", -1.0), ("inv_s_floor", float("inf")),
                                        ("inv_s_floor_start", 1.0)])
def test_bad_inv_s_floor_options_are_config_errors(key, value, tiny_scene, tmp_path):
    from va_plugin.errors import ConfigError

    with pytest.raises(ConfigError, match="inv_s_floor"):
        _trainer(tiny_scene, tmp_path, **{f"pipeline.model.{key}": value})
