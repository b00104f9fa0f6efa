"""A training step flushes denormals while it runs and leaves the process in IEEE mode after it."""

import torch
from conftest import tiny_config


def test_a_step_leaves_denormals_as_they_were(tiny_scene, tmp_path):
    trainer = tiny_config("neus", tiny_scene, tmp_path / "run", steps=1).setup()
    trainer.run_step()
    tiny = torch.full((1 << 16,), 1e-39)
    assert bool((tiny * 1.0 == tiny).all())
