"""Per-view image warps of the training targets: bilinear reading, the shift grid, registration, training."""

import json

import pytest
import torch

from conftest import tiny_config
from va_plugin.errors import ConfigError
from va_plugin.model_components.view_warp import (MAX_SHIFT, ViewWarpConfig, gaussian_blurred, sample_bilinear,
                                                  sample_bilinear_blur_slope)


def _module(views=3, **kw):
    return ViewWarpConfig(enabled=True, **kw).setup(num_views=views)


def test_bilinear_reading_hand_computed_and_clamped_at_the_border():
    image = torch.tensor([[0.0, 1.0, 2.0], [10.0, 11.0, 12.0]])[None, :, :, None]  # [1, 2, 3, 1]
    views = torch.zeros(4, dtype=torch.long)
    rows = torch.tensor([0.0, 0.5, 0.25, 5.0])
    cols = torch.tensor([1.5, 0.0, 1.0, -3.0])
    out = sample_bilinear(image, views, rows, cols)[:, 0]
    # (0, 1.5): between 1 and 2; (0.5, 0): between 0 and 10; (0.25, 1): 1 + 0.25 * 10; (5, -3): clamped to (1, 0)
    assert torch.allclose(out, torch.tensor([1.5, 5.0, 3.5, 10.0]))


def test_bilinear_reading_is_differentiable_in_the_position():
    torch.manual_seed(0)
    image = torch.rand(2, 6, 7, 3)
    views = torch.tensor([0, 1, 1])
    rows = torch.tensor([1.3, 2.6, 4.2], requires_grad=True)
    cols = torch.tensor([2.2, 0.4, 5.7], requires_grad=True)
    weights = torch.rand(3, 3)
    (sample_bilinear(image, views, rows, cols) * weights).sum().backward()
    eps = 1e-3
    for position, grad in ((rows, rows.grad), (cols, cols.grad)):
        for i in range(3):
            plus, minus = position.detach().clone(), position.detach().clone()
            plus[i] += eps
            minus[i] -= eps
            args = lambda p: (rows.detach(), p) if position is cols else (p, cols.detach())  # noqa: E731
            numeric = ((sample_bilinear(image, views, *args(plus)) - sample_bilinear(image, views, *args(minus)))
                       * weights).sum() / (2 * eps)
            assert grad[i].item() == pytest.approx(numeric.item(), abs=1e-3)


def test_shift_grid_values_frozen_and_unknown_views_and_the_clamp():
    module = _module(views=3, grid=3, penalty_weight=1.0)
    with torch.no_grad():
        grids = module.correction.view(3, 2, 3, 3)
        grids[1, 0] = 0.01    # view 1: x shift 1% of the image side everywhere
        grids[2, 1, 0, 0] = 0.02  # view 2: y shift at the top-left control point only
        grids[0] = 0.03       # view 0 is frozen: never applied
    views = torch.tensor([1, 2, 2, 0, -1])
    rows = torch.tensor([5, 0, 10, 3, 3])
    cols = torch.tensor([7, 0, 10, 3, 3])
    shifts = module.shifts(views, rows, cols, height=21, width=21)
    assert torch.allclose(shifts[0], torch.tensor([0.21, 0.0]))
    assert torch.allclose(shifts[1], torch.tensor([0.0, 0.42]))   # at the control point itself
    assert torch.allclose(shifts[2], torch.tensor([0.0, 0.0]))    # the centre control point: zero
    assert torch.equal(shifts[3:], torch.zeros(2, 2))
    # half-way between the top-left control point (0.02) and its right neighbour (0): half
    half = module.shifts(torch.tensor([2]), torch.tensor([0]), torch.tensor([5]), height=21, width=21)
    assert torch.allclose(half, torch.tensor([[0.0, 0.21]]))
    with torch.no_grad():
        module.correction.fill_(1.0)
    assert module.largest() == pytest.approx(MAX_SHIFT * 21)
    # the penalty: weight x mean square over view 1 and 2's 36 trained entries
    assert module.loss().item() == pytest.approx(1.0 * 1.0)


def test_registration_recovers_a_known_shift_of_one_view():
    """View 1 shows a smooth pattern moved by 1.5 px to the right; reading it through the learned warp
    and matching it against the unmoved pattern (what a consistent field renders) brings the warp to +1.5."""
    h = w = 32
    rows, cols = torch.meshgrid(torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32),
                                indexing="ij")
    pattern = lambda c: torch.stack([torch.sin(c / 3.0 + rows / 5.0), torch.cos(c / 4.0)], -1)  # noqa: E731
    images = torch.stack([pattern(cols), pattern(cols - 1.5)])  # view 1's content sits 1.5 px further right
    module = _module(views=2, grid=2, penalty_weight=0.0)
    optimizer = torch.optim.Adam(module.parameters(), lr=2e-3)
    views = torch.ones(h * w, dtype=torch.long)
    flat_rows, flat_cols = rows.reshape(-1).long(), cols.reshape(-1).long()
    inner = (flat_cols > 3) & (flat_cols < w - 4)
    target = pattern(cols).reshape(-1, 2)
    for _ in range(150):
        shifts = module.shifts(views, flat_rows, flat_cols, h, w)
        read = sample_bilinear(images, views, flat_rows + shifts[:, 1], flat_cols + shifts[:, 0])
        loss = ((read - target)[inner] ** 2).mean() + module.loss()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    final = module.shifts(views, flat_rows, flat_cols, h, w)
    assert final[:, 0].mean().item() == pytest.approx(1.5, abs=0.1)
    assert final[:, 1].abs().max().item() < 0.2


def test_gaussian_blur_hand_computed():
    image = torch.zeros(1, 9, 9, 2)
    image[0, 4, 4, 0] = 1.0  # a unit impulse in channel 0; channel 1 stays zero
    out = gaussian_blurred(image, 1.0)
    g = torch.exp(-0.5 * torch.arange(-3.0, 4.0) ** 2)
    g = g / g.sum()
    assert torch.allclose(out[0, 1:8, 1:8, 0], g[:, None] * g[None, :], atol=1e-6)
    assert out[0, ..., 0].sum().item() == pytest.approx(1.0, abs=1e-5)
    assert torch.equal(out[..., 1], torch.zeros(1, 9, 9))
    flat = torch.full((2, 5, 6, 3), 0.7)  # a constant image stays constant up to the border (replicated)
    assert torch.allclose(gaussian_blurred(flat, 2.5), flat)


def test_blur_slope_reading_keeps_the_sharp_values_and_takes_the_blurred_slope():
    torch.manual_seed(0)
    image = torch.rand(2, 12, 12, 3)
    blurred = gaussian_blurred(image, 2.0)
    views = torch.tensor([0, 1, 1])
    args = (torch.tensor([3.3, 5.6, 7.2]), torch.tensor([4.2, 6.4, 2.7]))
    rows, cols = (a.clone().requires_grad_(True) for a in args)
    weights = torch.rand(3, 3)
    out = sample_bilinear_blur_slope(image, blurred, views, rows, cols)
    assert torch.allclose(out, sample_bilinear(image, views, *args))
    (out * weights).sum().backward()
    ref_rows, ref_cols = (a.clone().requires_grad_(True) for a in args)
    (sample_bilinear(blurred, views, ref_rows, ref_cols) * weights).sum().backward()
    assert torch.allclose(rows.grad, ref_rows.grad) and torch.allclose(cols.grad, ref_cols.grad)


@pytest.mark.parametrize("sigma, recovered", [(0.0, False), (3.0, True)])
def test_blurred_slope_registers_a_shift_of_several_pixels(sigma, recovered):
    """A fine random texture moved by 4 px: the sharp slope sees only the pixel cell around each reading and
    stalls in a near minimum under a pixel away; the slope of a copy blurred by 3 px finds the shift (96 px
    images: the clamp is at 4.8 px)."""
    h = w = 96
    generator = torch.Generator().manual_seed(0)
    texture = gaussian_blurred(torch.rand(1, h, w + 8, 1, generator=generator), 1.0)[0]
    images = torch.stack([texture[:, 4:4 + w], texture[:, :w]])  # view 1's content sits 4 px further right
    blurred = gaussian_blurred(images, sigma) if sigma > 0 else images
    module = _module(views=2, grid=2, penalty_weight=0.0)
    optimizer = torch.optim.Adam(module.parameters(), lr=1e-3)
    rows, cols = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    flat_rows, flat_cols = rows.reshape(-1), cols.reshape(-1)
    views = torch.ones_like(flat_rows)
    inner = (flat_cols > 8) & (flat_cols < w - 8)
    target = images[0].reshape(-1, 1)
    for _ in range(200):
        shifts = module.shifts(views, flat_rows, flat_cols, h, w)
        read = sample_bilinear_blur_slope(images, blurred, views, flat_rows + shifts[:, 1],
                                          flat_cols + shifts[:, 0])
        loss = ((read - target)[inner] ** 2).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    found = module.shifts(views, flat_rows, flat_cols, h, w)[:, 0].mean().item()
    assert (abs(found - 4.0) < 0.25) == recovered, found
    assert found < 1.5 or recovered, found


def test_bad_options_are_config_errors():
    with pytest.raises(ConfigError, match="view_warp.grid"):
        _module(grid=1)
    with pytest.raises(ConfigError, match="penalty_weight"):
        _module(penalty_weight=-1.0)
    with pytest.raises(ConfigError, match="view_warp.start"):
        _module(start=1.0)
    with pytest.raises(ConfigError, match="gradient_blur"):
        _module(gradient_blur=-1.0)


@pytest.mark.parametrize("method", ["neus", "ngp"])
def test_training_warps_the_targets_of_unfrozen_views_only(method, tiny_scene, tmp_path):
    torch.manual_seed(0)
    config = tiny_config(method, tiny_scene, tmp_path / "run", steps=4,
                         **{"pipeline.model.view_warp.enabled": True, "pipeline.model.view_warp.start": 0.5})
    trainer = config.setup()
    model, pipeline = trainer.model, trainer.pipeline
    assert "view_warp" in model.get_param_groups()
    # before `start` the targets are the pixels' own values, after it they carry the warp's graph
    loss, _ = pipeline.train_step(0)
    assert not model.view_warp.active and "view_warp" in loss
    loss, _ = pipeline.train_step(2)
    assert model.view_warp.active
    with torch.no_grad():
        model.view_warp.correction.fill_(0.01)  # a shift that is off the pixel grid, so every slope counts
    loss, _ = pipeline.train_step(2)
    sum(loss.values()).backward()
    grad = model.view_warp.correction.grad
    assert torch.isfinite(grad).all() and grad[0].abs().sum() == 0 and grad[1:].abs().sum() > 0
    with torch.no_grad():
        model.view_warp.correction.zero_()
    record = trainer.train()
    assert record["warp_max_px"] > 0.0
    written = json.loads((tmp_path / "run" / "view_warp.json").read_text())
    assert written["rms_shift_px"][0] == 0.0 and len(written["rms_shift_px"]) == 4
    # off (the default): no parameters, no state-dict entry, no loss term
    plain = tiny_config(method, tiny_scene, tmp_path / "plain").setup()
    assert plain.model.view_warp is None and not any("warp" in k for k in plain.model.state_dict())
    assert "view_warp" not in plain.pipeline.train_step(0)[0]


def test_datamanager_reads_sharp_values_with_the_blurred_slope(tiny_scene, tmp_path):
    """``gradient_blur``: the warped targets keep the sharp inputs' values; the shift's gradient changes."""
    grads, values = [], []
    for sigma in (0.0, 2.0):
        torch.manual_seed(0)
        config = tiny_config("neus", tiny_scene, tmp_path / f"run{sigma}", steps=4,
                             **{"pipeline.model.view_warp.enabled": True, "pipeline.model.view_warp.start": 0.0,
                                "pipeline.model.view_warp.gradient_blur": sigma})
        pipeline = config.setup().pipeline
        warp, datamanager = pipeline.model.view_warp, pipeline.datamanager
        with torch.no_grad():
            warp.correction.fill_(0.01)
        _, batch = datamanager.next_train(0)
        out = datamanager.warped_targets(batch, warp)
        (out["rgb"].sum() + out["mask"].sum()).backward()
        grads.append(warp.correction.grad.clone())
        values.append(torch.cat([out["rgb"], out["mask"]], -1).detach())
    assert torch.allclose(values[0], values[1])
    assert torch.isfinite(grads[1]).all() and not torch.allclose(grads[0], grads[1])
