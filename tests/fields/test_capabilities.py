"""The ``Field`` interface's capability declarations: every registered method's field declares what it
implements (and nothing it lacks), and a field without the optional capabilities gets the defaults, which
the models read instead of probing for attributes."""

from dataclasses import dataclass, field

import pytest
import torch
from torch import nn

from va_plugin.adaptive.field import ViewAdaptiveField
from va_plugin.errors import ConfigError
from va_plugin.fields.base import Field, FieldConfig
from va_plugin.fields.encodings.hash_grid import HashGridEncoding
from va_plugin.models.base import Model, SceneInfo
from va_plugin.models.neus import NeuSModelConfig
from va_plugin.registry import builtin_methods, get_method

SCENE = SceneInfo(num_train_views=4, scene_radius=0.9)


def _method_field(name: str) -> Field:
    return get_method(name).make_config().pipeline.model.field.setup_for_scene(SCENE)


def _overrides(f: Field, name: str) -> bool:
    return getattr(type(f), name) is not getattr(Field, name)


def _encodings(f: Field) -> list[HashGridEncoding]:
    return [m for m in f.modules() if isinstance(m, HashGridEncoding)]


@pytest.mark.parametrize("name", sorted(builtin_methods()))
def test_each_method_field_declares_what_it_implements(name):
    torch.manual_seed(0)
    f = _method_field(name)
    assert isinstance(f, Field) and f.geometry_kind in ("sdf", "density")
    assert f.current_phase == 1  # every field starts in phase 1; one without phases stays there
    assert isinstance(f.analytic_sdf_gradient, bool) and isinstance(f.has_view_branches, bool)
    points = torch.rand(5, 3) - 0.5
    if f.analytic_sdf_gradient:  # declared: implemented, and it runs on the field's network
        assert f.geometry_kind == "sdf" and _overrides(f, "geometry_and_gradient")
        sdf, features, gradient = f.geometry_and_gradient(points)
        reference_sdf, reference_features = f.geometry(points)
        assert gradient.shape == (5, 3) and torch.allclose(sdf, reference_sdf, atol=1e-6)
        assert torch.allclose(features, reference_features, atol=1e-6)
    else:  # not declared: the interface's default refuses
        with pytest.raises(NotImplementedError):
            f.geometry_and_gradient(points)
    # per-view branches: exactly the view-adaptive methods, with the wrapper's queries
    assert f.has_view_branches == isinstance(f, ViewAdaptiveField) == name.startswith("va-")
    if f.has_view_branches:
        assert f.branches_active() is False and f.attention_matrix() is None  # phase 1, nothing recorded
        assert f.analytic_sdf_gradient == f.base.analytic_sdf_gradient and f.bound == f.base.bound
        assert not f.base.has_view_branches
        assert _overrides(f, "extra_losses") and _overrides(f, "training_callbacks")
        assert len(f.training_callbacks()) >= 1
    # the bound is the hash grid's extent where there is one, else None
    grids = _encodings(f)
    if grids:
        assert f.bound is not None and all(f.bound == g.bound for g in grids)
    else:
        assert f.bound is None
    # the hooks answer with their types on any field
    assert isinstance(f.extra_losses({}), dict) and isinstance(f.diagnostics(), dict)
    assert isinstance(f.training_callbacks(), list)


@pytest.mark.parametrize("name", ["neus", "va-neus"])
def test_neus_methods_take_the_analytic_gradient_their_field_declares(name):
    f = _method_field(name)
    assert f.analytic_sdf_gradient  # the SDF network's softplus and linear output are covered
    net = (f.base if f.has_view_branches else f).sdf_net
    net.activation = nn.Tanh()  # not covered by the hand-written chain rule
    assert not f.analytic_sdf_gradient
    with pytest.raises(NotImplementedError):
        f.geometry_and_gradient(torch.zeros(1, 3))


class _PlainField(Field):
    """A field with the required queries only: a linear SDF and a constant color."""

    feature_dim = 4

    def __init__(self, config):
        super().__init__()
        self.config = config
        self.net = nn.Linear(3, 3)

    def geometry(self, positions):
        out = self.net(positions)
        return out[..., :1], out[..., 1:]

    def color_features(self, positions, directions, normals, geo_features):
        return torch.zeros(positions.shape[:-1] + (self.feature_dim,))

    def decode_color(self, features):
        return torch.full(features.shape[:-1] + (3,), 0.5)


@dataclass
class _PlainFieldConfig(FieldConfig):
    _target: type = field(default_factory=lambda: _PlainField)


def test_a_field_without_the_optional_capabilities_gets_the_defaults():
    f = _PlainFieldConfig().setup_for_scene(SCENE)
    assert not f.analytic_sdf_gradient and not f.has_view_branches and f.bound is None
    assert f.extra_losses({"rgb": torch.zeros(2, 3)}, None, None) == {}
    assert f.training_callbacks() == [] and f.diagnostics() == {}
    with pytest.raises(NotImplementedError):
        f.geometry_and_gradient(torch.zeros(1, 3))
    f.update_step(3, 10)  # no schedules: nothing happens
    assert f.param_groups() == {"fields": list(f.parameters())}


def test_a_model_reads_the_defaults_of_such_a_field():
    model = NeuSModelConfig(field=_PlainFieldConfig()).setup(scene=SCENE)
    assert model.sdf_gradient == "autograd"  # "auto": the field declares no analytic gradient
    assert model.training_callbacks() == []
    assert set(model.diagnostics()) == {"inv_s", "samples_per_ray", "probed_per_ray"}  # the model's own only
    losses = {"rgb": torch.tensor(1.0)}
    assert model.apply_extra_losses(dict(losses), {}, {}) == losses
    model.update_step(2)
    assert model.step == 2
    grid = torch.rand(3, 3, 3).numpy()
    assert model.prepare_mesh_grid(grid, 0.1) is grid and model.fill_mesh_cavities is False
    assert Model.prepare_mesh_grid is type(model).prepare_mesh_grid
    with pytest.raises(ConfigError, match="analytic SDF gradient"):
        NeuSModelConfig(field=_PlainFieldConfig(), sdf_gradient="analytic").setup(scene=SCENE)
