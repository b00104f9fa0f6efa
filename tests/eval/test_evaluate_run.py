"""evaluate_run: the renders it scores are the ones it saves, and a mesh handed in is the mesh scored."""

import numpy as np
import pytest
from conftest import tiny_config

from va_plugin.data.images import read_image
from va_plugin.eval.evaluate import FSCORE_THRESHOLD, evaluate_run, ground_truth_mesh_path, image_metrics, load_mesh
from va_plugin.eval.geometry import geometry_metrics
from va_plugin.eval.image import psnr
from va_plugin.export.render import render_view


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A neus pipeline after 2 steps on a 32-px mug (LPIPS-Alex needs at least 31 px)."""
    from va_plugin.bench.scenes.builder import build_procedural_scene

    scene = build_procedural_scene(tmp_path_factory.mktemp("scene32"), "mug", n_views=4, resolution=32)
    trainer = tiny_config("neus", scene, tmp_path_factory.mktemp("run"), steps=2).setup()
    trainer.train()
    return trainer


def test_saved_views_are_the_scored_renders(trained, tmp_path):
    pipeline = trained.pipeline
    out = image_metrics(pipeline, max_views=2, use_lpips=False, progress=False, render_dir=tmp_path)
    assert out["image_params"]["views"] == 2 and out["image_params"]["width"] == 32
    scores = []
    for i in range(2):
        pair = read_image(tmp_path / f"view_{i:03d}.png")[:, :, :3]
        render, target = pair[:, :32], pair[:, 32:]
        # the saved render is the canonical render of held-out view i (8-bit rounding apart)
        direct = render_view(pipeline.model, pipeline.datamanager.test.cameras, i)
        assert np.abs(render - direct).max() <= 1.0 / 255 + 1e-6
        assert np.abs(target - pipeline.datamanager.test.images[i].numpy()).max() <= 1.0 / 255 + 1e-6
        scores.append(psnr(direct, pipeline.datamanager.test.images[i].numpy()))
    assert out["psnr"] == pytest.approx(float(np.mean(scores)), rel=1e-6)
    assert not (tmp_path / "view_002.png").exists()


def test_a_mesh_handed_in_is_the_mesh_scored(trained):
    pipeline = trained.pipeline
    truth = load_mesh(ground_truth_mesh_path(pipeline))
    state = {"method_name": "neus", "step": trained.step, "train_seconds": 1.0}
    result = evaluate_run(pipeline, state, max_views=1, n_samples=4000, progress=False, mesh=truth)
    # exactly the scores of the ground truth against itself (same samples, same seed), which a 2-step
    # field would be nowhere near
    same = geometry_metrics(truth, truth, n_samples=4000, threshold=FSCORE_THRESHOLD)
    assert result["cd"] == pytest.approx(same["chamfer_distance"], rel=1e-9)
    assert result["iou"] == pytest.approx(same["volume_iou"]) and result["iou"] > 0.95
    assert result["fscore"] == pytest.approx(same["f_score"])
    assert result["steps"] == 2 and np.isfinite(result["lpips"])
