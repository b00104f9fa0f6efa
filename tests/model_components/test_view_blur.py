"""Per-view learned blur: the ring of rays, the colour mix, learning a known blur, training with it."""

import json
import math

import pytest
import torch

from conftest import tiny_config
from va_plugin.errors import ConfigError
from va_plugin.model_components.view_blur import RING, ViewBlurConfig


def _module(views=3, **kw):
    return ViewBlurConfig(enabled=True, **kw).setup(num_views=views)


def test_ring_rays_sit_on_a_cross_around_each_pixel():
    torch.manual_seed(0)
    blur = _module(radius=2.0)
    rows, cols = torch.tensor([5, 10, 20]), torch.tensor([7, 3, 30])
    sub_rows, sub_cols = blur.sub_pixels(rows, cols)
    assert sub_rows.shape == (3 * (1 + RING),)
    assert torch.equal(sub_rows[:3], rows.float()) and torch.equal(sub_cols[:3], cols.float())
    dr = sub_rows[3:].reshape(RING, 3) - rows.float()
    dc = sub_cols[3:].reshape(RING, 3) - cols.float()
    assert torch.allclose(torch.sqrt(dr**2 + dc**2), torch.full((RING, 3), 2.0), atol=1e-5)
    # a cross: the four offsets of a pixel cancel, and consecutive ones are perpendicular
    assert torch.allclose(dr.sum(0), torch.zeros(3), atol=1e-5) and torch.allclose(dc.sum(0), torch.zeros(3), atol=1e-5)
    assert torch.allclose(dr[0] * dr[1] + dc[0] * dc[1], torch.zeros(3), atol=1e-5)
    # the covariance of the offsets is isotropic: radius^2 / 2 per axis
    assert torch.allclose((dr**2).mean(0), torch.full((3,), 2.0), atol=1e-4)


def test_colours_are_mixed_by_the_view_weight_and_other_outputs_keep_the_pixel_ray():
    blur = _module(views=2, init_weight=0.2)
    with torch.no_grad():
        blur.correction[1, 0] = math.log(0.6 / 0.4) - math.log(0.2 / 0.8)  # view 1: weight 0.6
    views = torch.tensor([0, 1])
    centre = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    ring = torch.tensor([[0.0, 0.0, 1.0], [1.0, 1.0, 1.0]]).repeat(RING, 1)  # every ring ray of pixel k alike
    outputs = {"rgb": torch.cat([centre, ring]), "rgb_shared": torch.cat([centre, ring]),
               "accumulation": torch.arange(10.0)[:, None], "weights": torch.ones(17)}
    out = blur.combine(outputs, views)
    expected = torch.tensor([[0.8, 0.0, 0.2], [0.6, 1.0, 0.6]])
    assert torch.allclose(out["rgb"], expected, atol=1e-6) and torch.allclose(out["rgb_shared"], expected, atol=1e-6)
    assert torch.equal(out["accumulation"], torch.tensor([[0.0], [1.0]]))
    assert out["weights"].shape == (17,)  # per-sample outputs stay whole
    assert torch.allclose(blur.sigma_px(), torch.tensor([2.5 * math.sqrt(0.1), 2.5 * math.sqrt(0.3)]))


def test_a_known_blur_is_learned_from_the_photometric_loss_alone():
    """A sharp image (a sine grating) seen by view 1 through the ring PSF at weight 0.7, by view 0 sharp:
    fitting the weights to the targets recovers 0.7 and about 0."""
    torch.manual_seed(0)
    blur = _module(views=2, radius=2.0, init_weight=0.3)
    truth = _module(views=2, radius=2.0, init_weight=0.3)
    with torch.no_grad():
        truth.correction[0, 0] = -8.0
        truth.correction[1, 0] = math.log(0.7 / 0.3) - math.log(0.3 / 0.7)
    scene = lambda r, c: torch.stack([torch.sin(0.9 * c) * torch.cos(0.6 * r), torch.sin(0.4 * r), torch.cos(c)], -1)
    optimizer = torch.optim.Adam(blur.parameters(), lr=0.05)
    for _ in range(300):
        views = torch.randint(0, 2, (256,))
        rows, cols = torch.rand(256) * 50, torch.rand(256) * 50
        sub_rows, sub_cols = truth.sub_pixels(rows, cols)
        target = truth.combine({"rgb": scene(sub_rows, sub_cols)}, views)["rgb"]
        sub_rows, sub_cols = blur.sub_pixels(rows, cols)
        pred = blur.combine({"rgb": scene(sub_rows, sub_cols)}, views)["rgb"]
        optimizer.zero_grad()
        ((pred - target) ** 2).mean().backward()
        optimizer.step()
    weights = blur.weights().detach()
    assert weights[1] == pytest.approx(0.7, abs=0.05) and weights[0] < 0.05


def test_frozen_views_keep_their_start_weight():
    blur = _module(views=3, frozen_views=(0,), init_weight=0.25)
    with torch.no_grad():
        blur.correction.fill_(2.0)
    weights = blur.weights()
    assert weights[0].item() == pytest.approx(0.25) and weights[1].item() > 0.25


def test_bad_options_are_config_errors():
    for kw, key in (({"radius": 0.0}, "view_blur.radius"), ({"radius": float("nan")}, "view_blur.radius"),
                    ({"init_weight": 1.0}, "view_blur.init_weight"), ({"start": 1.0}, "view_blur.start"),
                    ({"penalty_weight": -1.0}, "view_blur.penalty_weight")):
        with pytest.raises(ConfigError, match=key):
            _module(**kw)


@pytest.mark.parametrize("method", ["neus", "va-neus"])
def test_training_renders_each_pixel_through_its_view_blur(method, tiny_scene, tmp_path):
    torch.manual_seed(0)
    config = tiny_config(method, tiny_scene, tmp_path / "run", steps=4,
                         **{"pipeline.model.view_blur.enabled": True, "pipeline.model.view_blur.start": 0.5})
    trainer = config.setup()
    model, pipeline = trainer.model, trainer.pipeline
    assert "view_blur" in model.get_param_groups()
    assert not model.view_blur.active  # before `start` every ray is a pixel of its own
    pipeline.train_step(2)
    assert model.view_blur.active
    loss, _ = pipeline.train_step(2)
    sum(loss.values()).backward()
    grad = model.view_blur.correction.grad
    assert torch.isfinite(grad).all() and grad.abs().sum() > 0
    model.view_blur.correction.grad = None
    record = trainer.train()
    assert record["blur_max_px"] > 0.0
    written = json.loads((tmp_path / "run" / "view_blur.json").read_text())
    assert len(written["sigma_px"]) == 4
    # off (the default): no parameters, no state-dict entry
    plain = tiny_config(method, tiny_scene, tmp_path / "plain").setup()
    assert plain.model.view_blur is None and not any("blur" in k for k in plain.model.state_dict())


def test_the_blurred_share_of_a_batch_keeps_its_mix_of_foreground_and_background(tiny_scene, tmp_path):
    """A batch is laid out foreground pixels first: the blurred fifth must not be all foreground."""
    from va_plugin.model_components.view_blur import blurred_batch

    torch.manual_seed(0)
    trainer = tiny_config("neus", tiny_scene, tmp_path / "run", steps=2,
                          **{"pipeline.model.view_blur.enabled": True}).setup()
    datamanager = trainer.pipeline.datamanager
    rays, batch = datamanager.next_train(0)
    sub_rays, sub_batch, views = blurred_batch(trainer.model.view_blur, datamanager.cameras, rays, batch)
    n = len(sub_batch["pixel"])
    assert n == -(-len(rays) // (1 + RING)) and len(sub_rays) == n * (1 + RING)
    share = lambda b: float((b["mask"] > 0.5).float().mean())  # noqa: E731
    assert abs(share(sub_batch) - share(batch)) < 0.2 and share(sub_batch) < 0.99
    # the pixels' own rays come first, identical to the batch's rays for those pixels
    assert torch.allclose(sub_rays.directions[:n], rays.directions[::1 + RING], atol=1e-6)
