"""Training rays through a random point of their pixel (pipeline.datamanager.pixel_jitter)."""

import torch

from conftest import tiny_config


def _datamanager(tiny_scene, tmp_path, jitter):
    config = tiny_config("neus", tiny_scene, tmp_path, **{"pipeline.datamanager.pixel_jitter": jitter})
    return config.setup().pipeline.datamanager


def test_jittered_rays_stay_inside_their_pixel_and_keep_its_target(tiny_scene, tmp_path):
    plain = _datamanager(tiny_scene, tmp_path / "plain", False)
    jittered = _datamanager(tiny_scene, tmp_path / "jittered", True)
    rays_p, batch_p = plain.next_train(0)
    rays_j, batch_j = jittered.next_train(0)
    # the same pixels and targets (the offsets are drawn after the pixels), other rays
    assert torch.equal(batch_p["pixel"], batch_j["pixel"]) and torch.equal(batch_p["rgb"], batch_j["rgb"])
    assert not torch.allclose(rays_p.directions, rays_j.directions)
    cameras = jittered.cameras
    views, rows, cols = batch_j["pixel"].unbind(-1)
    for view in views.unique().tolist():
        at = views == view
        uv, depth = cameras.project(rays_j.origins[at] + rays_j.directions[at], view)
        # pixel (row, col) spans image-plane coordinates [col - 0.5, col + 0.5) in index units
        assert (depth > 0).all()
        assert ((uv[:, 0] - cols[at]).abs() <= 0.5 + 1e-4).all() and ((uv[:, 1] - rows[at]).abs() <= 0.5 + 1e-4).all()
        assert (uv[:, 0] - cols[at]).abs().max() > 0.1  # they do move off the centre
    # the plain rays go through the centres
    at = views == 0
    uv, _ = plain.cameras.project(rays_p.origins[at] + rays_p.directions[at], 0)
    assert torch.allclose(uv, torch.stack([cols[at], rows[at]], -1).float(), atol=1e-3)


def test_jittered_training_resumes_bitwise(tiny_scene, tmp_path):
    from va_plugin.engine.callbacks import BEFORE_STEP, TrainingCallback

    overrides = {"pipeline.datamanager.pixel_jitter": True, "checkpoint_every": 2}
    full = tiny_config("neus", tiny_scene, tmp_path / "full", steps=4, **overrides).setup()
    full.train()

    def interrupt(step, trainer):
        if step == 2:
            raise KeyboardInterrupt

    first = tiny_config("neus", tiny_scene, tmp_path / "cut", steps=4, **overrides).setup()
    first.callbacks.append(TrainingCallback(interrupt, BEFORE_STEP))
    try:
        first.train()
    except KeyboardInterrupt:
        pass
    second = tiny_config("neus", tiny_scene, tmp_path / "cut", steps=4, **overrides).setup()
    assert second.resume() and second.step == 2
    second.train()
    a, b = full.model.state_dict(), second.model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
