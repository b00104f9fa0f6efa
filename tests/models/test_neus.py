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


def test_surface_crossings_hand_computed():
    from va_plugin.model_components.neus import surface_crossings

    torch.manual_seed(0)
    sphere = lambda p: p.norm(dim=-1) - 0.5
    two_spheres = lambda p: torch.minimum((p - torch.tensor([-0.5, 0.0, 0.0])).norm(dim=-1),
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
    two_spheres = lambda p: torch.minimum((p - torch.tensor([-0.32, 0.0, 0.0])).norm(dim=-1),
                                          (p - torch.tensor([0.32, 0.0, 0.0])).norm(dim=-1)) - 0.3 + offset * (
        p[..., 0].abs() < 0.05)
    origin, direction = torch.tensor([[-2.0, 0.0, 0.0]]), torch.tensor([[1.0, 0.0, 0.0]])
    near, far = torch.full((1, 1), 1.0), torch.full((1, 1), 3.0)
    surface_crossings(two_spheres, origin, direction, near, far, 64).sum().backward()
    assert float(offset.grad) > 0.5  # lowering the SDF in the gap (filling it) lowers the count
    # deep inside a convex body the indicator is saturated: no gradient there
    offset.grad = None
    inner = lambda p: p.norm(dim=-1) - 0.6 + offset * (p.norm(dim=-1) < 0.2)
    surface_crossings(inner, origin, direction, near, far, 64).sum().backward()
    assert abs(float(offset.grad)) < 1e-3


def test_crossings_prior_is_a_finite_loss_after_its_start(tiny_scene, tmp_path):
    trainer = _trainer(tiny_scene, tmp_path, **{"pipeline.model.crossings_weight": 1.0,
                                                "pipeline.model.crossings_start": 0.0})
    model = trainer.model
    rays, batch = trainer.pipeline.datamanager.next_train(0)
    loss = model.get_loss_dict(model.get_outputs(rays), batch)["crossings"]
    assert torch.isfinite(loss) and 0.0 <= float(loss.detach()) <= model.config.crossings_samples / 2
    loss.backward()
    grads = [p.grad for p in model.field.parameters() if p.grad is not None]
    assert grads and all(torch.isfinite(g).all() for g in grads) and any(float(g.abs().max()) > 0 for g in grads)
    late = _trainer(tiny_scene, tmp_path / "late", **{"pipeline.model.crossings_weight": 1.0,
                                                     "pipeline.model.crossings_start": 0.5})
    assert "crossings" not in late.model.get_loss_dict(late.model.get_outputs(rays), batch)


def test_crossings_prior_is_off_on_orthographic_scenes_without_normal_maps():
    from va_plugin.data.rigfile import builtin_rigs, rig_cameras
    from va_plugin.models.base import SceneInfo
    from va_plugin.models.neus import NeuSModelConfig

    def weight(rig, has_normals=False, **options):
        cameras = rig_cameras(builtin_rigs()[rig], 16)
        scene = SceneInfo(num_train_views=len(cameras), scene_radius=1.0, train_cameras=cameras,
                          has_normals=has_normals)
        return NeuSModelConfig(crossings_weight=0.05, **options).setup(scene=scene).crossings_weight

    assert weight("mvadapter") == 0.0  # orthographic, no normal maps
    assert weight("mvadapter", has_normals=True) == 0.05
    assert weight("mvadapter", crossings_orthographic=True) == 0.05
    assert weight("four-view-grid") == 0.05  # perspective


@pytest.mark.parametrize("key, value", [("crossings_weight", -0.1), ("crossings_rays", 0), ("crossings_samples", 1),
                                        ("crossings_start", 1.5)])
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


def test_inv_s_floor_rises_from_its_start_and_lifts_the_learned_value(tiny_scene, tmp_path):
    trainer = _trainer(tiny_scene, tmp_path, **{"pipeline.model.inv_s_floor": 500.0,
                                                "pipeline.model.inv_s_floor_start": 0.5,
                                                "max_steps": 8, "schedule_steps": 8})
    model, steps = trainer.model, trainer.model.scene.schedule_steps
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
