"""Per-view uncertainty of the colour loss: running errors, the weights they give, and the model option."""

import pytest
import torch

from va_plugin.errors import ConfigError
from va_plugin.model_components.view_uncertainty import MAX_RATIO, MOMENTUM, ViewUncertainty


def pixels(views, rows=None, cols=None):
    views = torch.as_tensor(views)
    rows = torch.zeros_like(views) if rows is None else torch.as_tensor(rows)
    cols = torch.zeros_like(views) if cols is None else torch.as_tensor(cols)
    return torch.stack([views, rows, cols], -1)


def test_weights_are_inverse_running_errors_normalised_to_mean_one():
    vu = ViewUncertainty(num_views=2, grid=1, power=1.0, width=8, height=8)
    assert torch.equal(vu.weights(pixels([0, 1])), torch.ones(2))  # nothing measured yet: plain mean
    vu.update(pixels([0, 0, 1, 1]), torch.tensor([0.005, 0.015, 0.03, 0.05]))  # means 0.01 and 0.04
    # reference 0.025: ratios 2.5 and 0.625, over their mean 1.5625
    assert torch.allclose(vu.weights(pixels([0, 1])), torch.tensor([1.6, 0.4]))
    vu.update(pixels([1]), torch.tensor([0.14]))  # view 1 only: 0.98 * 0.04 + 0.02 * 0.14
    assert torch.allclose(vu.error.view(-1), torch.tensor([0.01, MOMENTUM * 0.04 + (1 - MOMENTUM) * 0.14]))


def test_weights_are_clamped_and_a_second_power_sharpens_them():
    vu = ViewUncertainty(num_views=2, grid=1, power=1.0, width=8, height=8)
    vu.update(pixels([0, 1]), torch.tensor([1e-4, 1.0]))
    cells = vu.cell_weights().view(-1)
    assert torch.allclose(cells, torch.tensor([MAX_RATIO, 0.50005 / 1.0]), rtol=1e-4)
    squared = ViewUncertainty(num_views=2, grid=1, power=2.0, width=8, height=8)
    squared.update(pixels([0, 1]), torch.tensor([0.02, 0.03]))
    single = ViewUncertainty(num_views=2, grid=1, power=1.0, width=8, height=8)
    single.update(pixels([0, 1]), torch.tensor([0.02, 0.03]))
    assert torch.allclose(squared.cell_weights(), single.cell_weights() ** 2)


def test_cells_split_each_view_and_background_rays_are_left_alone():
    vu = ViewUncertainty(num_views=1, grid=2, power=1.0, width=8, height=8)
    where = pixels([0, 0, 0, 0], rows=[1, 1, 6, 6], cols=[1, 6, 1, 6])
    assert vu.cells(where).tolist() == [0, 1, 2, 3]
    keep = torch.tensor([True, True, True, False])  # the last ray is background
    vu.update(where, torch.tensor([0.01, 0.01, 0.04, 5.0]), keep)
    assert vu.seen.view(-1).tolist() == [1, 1, 1, 0] and vu.error.view(-1)[3] == 0
    w = vu.weights(where, keep)
    assert w[3] == 1 and torch.isclose(w[:3].mean(), torch.tensor(1.0)) and w[2] < w[0] == w[1]


def test_the_model_option_trains_keeps_its_errors_in_the_checkpoint_and_refuses_bad_values(tiny_scene, tmp_path):
    from conftest import tiny_config

    config = tiny_config("neus", tiny_scene, tmp_path / "run", steps=3, **{
        "pipeline.model.view_uncertainty": 1.0, "pipeline.model.view_uncertainty_grid": 2,
        "pipeline.model.view_uncertainty_start": 0.0})
    trainer = config.setup()
    record = trainer.train()
    model = trainer.pipeline.model
    assert model.view_uncertainty.seen.sum() > 0 and torch.isfinite(model.view_uncertainty.error).all()
    assert "view_uncertainty.error" in model.state_dict()
    assert 1.0 / MAX_RATIO <= record["view_weight_min"] <= record["view_weight_max"] <= MAX_RATIO
    for key, value in (("view_uncertainty", -1), ("view_uncertainty", "nan"), ("view_uncertainty_grid", 0),
                       ("view_uncertainty_start", 2)):
        with pytest.raises(ConfigError, match="view_uncertainty"):
            tiny_config("neus", tiny_scene, tmp_path / "bad", **{f"pipeline.model.{key}": value}).setup()
