import pytest
import torch
from conftest import tiny_config

from va_plugin.errors import ConfigError, VAError
from va_plugin.export.mesh import extract_mesh

SMALL = {"pipeline.model.occupancy_grid.resolution": 16, "pipeline.model.occupancy_grid.warmup_steps": 2,
         "pipeline.model.occupancy_grid.update_every": 1, "pipeline.model.field.n_levels": 6,
         "pipeline.model.field.log2_hashmap_size": 12, "pipeline.model.field.max_resolution": 64}


def _trainer(tiny_scene, tmp_path, steps=2, **overrides):
    torch.manual_seed(0)
    return tiny_config("ngp", tiny_scene, tmp_path / "ngp", steps=steps, **{**SMALL, **overrides}).setup()


class Spy:
    """Counts the points a field evaluates and records what field.color receives."""

    def __init__(self, field):
        self.positions, self.color_calls = [], []
        geometry, color = field.geometry, field.color

        def counting_geometry(positions):
            self.positions.append(positions.detach().reshape(-1, 3))
            return geometry(positions)

        def recording_color(positions, directions, normals, geo_features, camera_indices=None, weights=None,
                            ray_indices=None):
            self.color_calls.append((positions.shape, camera_indices, ray_indices))
            return color(positions, directions, normals, geo_features, camera_indices, weights=weights,
                         ray_indices=ray_indices)

        field.geometry, field.color = counting_geometry, recording_color

    @property
    def points(self) -> int:
        return sum(p.shape[0] for p in self.positions)


def test_all_empty_grid_renders_background_with_finite_gradients(tiny_scene, tmp_path):
    trainer = _trainer(tiny_scene, tmp_path)
    model = trainer.model
    model.occupancy_grid.binary.fill_(False)
    rays, batch = trainer.pipeline.datamanager.next_train(0)
    outputs = model.get_outputs(rays)
    assert torch.allclose(outputs["rgb"], model.background.expand_as(outputs["rgb"]))
    assert (outputs["accumulation"] == 0).all() and outputs["weights"].numel() == 0
    assert all(torch.isfinite(v).all() for v in outputs.values())
    loss = sum(model.get_loss_dict(outputs, batch).values())
    loss.backward()
    assert torch.isfinite(loss)
    assert all(p.grad is None or torch.isfinite(p.grad).all() for p in model.parameters())


def test_empty_cells_are_skipped_before_the_field_runs(tiny_scene, tmp_path):
    trainer = _trainer(tiny_scene, tmp_path, **{"pipeline.model.early_stop_transmittance": 0.0})
    model = trainer.model
    rays, _ = trainer.pipeline.datamanager.next_train(0)
    grid = model.occupancy_grid
    r = grid.resolution
    grid.binary.zero_()
    grid.binary[: r // 2] = True  # only the x < 0 half is occupied
    spy = Spy(model.field)
    outputs = model.get_outputs(rays)
    n_rays, n_samples = len(rays), model.config.n_samples
    assert 0 < spy.points < n_rays * n_samples
    evaluated = torch.cat(spy.positions)
    assert grid.occupied(evaluated).all() and (evaluated[:, 0] < 1e-6).all()
    # each kept sample was evaluated once, and color saw the same points
    assert spy.color_calls[0][0][0] == spy.points == outputs["weights"].shape[0]
    assert model.samples_per_ray == pytest.approx(spy.points / n_rays)


def test_early_termination_skips_samples_behind_opaque_points(tiny_scene, tmp_path):
    counts = {}
    for stop in (0.0, 1e-4):
        trainer = _trainer(tiny_scene, tmp_path / str(stop), **{"pipeline.model.early_stop_transmittance": stop})
        model = trainer.model
        with torch.no_grad():
            model.field.density_net.out.bias[0] = 8.0  # opaque everywhere: rays stop after a few samples
        rays, batch = trainer.pipeline.datamanager.next_train(0)
        outputs = model.get_outputs(rays)
        sum(model.get_loss_dict(outputs, batch).values()).backward()
        counts[stop] = model.samples_per_ray
        assert torch.allclose(outputs["accumulation"][rays.fars[:, 0] > rays.nears[:, 0] + 0.1], torch.ones(1),
                              atol=1e-3)
    assert counts[1e-4] < 0.5 * counts[0.0]


def test_color_gets_each_samples_camera_index_and_weights_match(tiny_scene, tmp_path):
    trainer = _trainer(tiny_scene, tmp_path)
    model = trainer.model
    spy = Spy(model.field)
    rays, _ = trainer.pipeline.datamanager.next_train(0)
    outputs = model.get_outputs(rays)
    shape, camera, ray = spy.color_calls[-1]
    assert camera.dtype == torch.long and camera.shape == shape[:-1] == outputs["weights"].shape == ray.shape
    assert torch.equal(camera, rays.camera_indices[ray])  # each sample knows its ray
    assert bool((ray[1:] >= ray[:-1]).all())  # packed ray by ray
    assert {"rgb", "accumulation", "depth"} <= set(outputs)
    assert outputs["rgb"].shape == (len(rays), 3) and outputs["depth"].shape == (len(rays), 1)


def test_grid_update_runs_through_the_training_callbacks(tiny_scene, tmp_path):
    trainer = _trainer(tiny_scene, tmp_path, steps=4)
    trainer.train()
    record = trainer.model.diagnostics()
    assert "samples_per_ray" in record and 0.0 < record["occupied_fraction"] <= 1.0
    assert trainer.model.occupancy_grid.values.sum() > 0  # the callback filled the grid


def test_grid_switch_and_bad_config(tiny_scene, tmp_path):
    trainer = _trainer(tiny_scene, tmp_path, **{"pipeline.model.occupancy_grid.enabled": False})
    assert trainer.model.occupancy_grid is None and trainer.model.training_callbacks() == []
    trainer.train()
    assert trainer.model.samples_per_ray > 0
    with pytest.raises(ConfigError, match="density_threshold"):
        _trainer(tiny_scene, tmp_path / "bad", **{"pipeline.model.density_threshold": -1.0})
    with pytest.raises(ConfigError, match="bound"):
        _trainer(tiny_scene, tmp_path / "bound", **{"pipeline.model.field.bound": 0.5})


def test_mesh_export_after_brief_training(tiny_scene, tmp_path):
    trainer = _trainer(tiny_scene, tmp_path, steps=30)
    trainer.train()
    model = trainer.model
    with torch.no_grad():
        density = model.density(torch.rand(4096, 3) * 1.2 - 0.6)
    # a threshold above every density: no surface, and a clear error instead of a crash
    model.config.density_threshold = float(density.max()) * 1e3 + 1.0
    with pytest.raises(VAError, match="no surface"):
        extract_mesh(model, resolution=24)
    model.config.density_threshold = float(density.median())
    mesh = extract_mesh(model, resolution=24)
    assert len(mesh.faces) > 0 and mesh.visual.vertex_colors.shape[0] == len(mesh.vertices)


def test_the_memory_estimate_reads_each_model_configs_own_samples():
    from va_plugin.models.base import ModelConfig
    from va_plugin.models.neus import NeuSModelConfig
    from va_plugin.models.ngp import NGPModelConfig

    assert NGPModelConfig(n_samples=40).samples_per_ray() == 40
    assert NeuSModelConfig(n_samples=24, n_importance=16).samples_per_ray() == 40
    assert ModelConfig().samples_per_ray() == 0  # a model config that does not sample rays: no estimate
