import json

import numpy as np
import pytest
from conftest import tiny_config

from va_plugin.analysis.diagnostics import attention_picture, overlap_scores
from va_plugin.bench.scenes.builder import build_procedural_scene
from va_plugin.cli.export import main as export_main
from va_plugin.data.images import read_image


def test_overlap_scores_against_hand_values():
    injected = np.zeros((10, 10))
    injected[:2] = 0.5  # 20 perturbed pixels: chance 0.2
    perfect = injected + 0.01
    scores = overlap_scores(perfect, injected)
    assert scores["chance"] == pytest.approx(0.2)
    assert scores["precision_top10"] == pytest.approx(1.0)
    assert scores["pearson"] == pytest.approx(1.0)
    wrong = np.zeros((10, 10))
    wrong[5:7] = 1.0
    assert overlap_scores(wrong, injected)["precision_top10"] == 0.0
    assert overlap_scores(np.zeros((10, 10)), injected)["pearson"] is None


def test_attention_picture_is_an_image_of_the_matrix():
    picture = attention_picture(np.array([[0.7, 0.3], [0.1, 0.9]]), cell=32)
    assert picture.dtype == np.uint8 and picture.shape == (2 * 32 + 28, 2 * 32 + 28, 3)


def test_a_run_writes_attention_and_inconsistency_maps(tmp_path_factory, tmp_path):
    scene = build_procedural_scene(tmp_path_factory.mktemp("l2"), "mug", n_views=4, resolution=16, level=2)
    trainer = tiny_config("va-neus", scene, tmp_path / "run", steps=6, **{
        "pipeline.model.field.skip_consistent_scenes": "false", "pipeline.model.field.diagnostics_scale": 1.0,
        "pipeline.model.field.min_sample_weight": 0.0}).setup()
    trainer.train()
    run = tmp_path / "run"
    attention = json.loads((run / "attention.json").read_text())
    matrix = np.array(attention["rows_query_view_cols_key_view"])
    assert matrix.shape == (4, 4) and np.allclose(matrix.sum(1), 1.0, atol=1e-3)
    record = json.loads((run / "inconsistency.json").read_text())
    assert len(record["views"]) == 4
    assert record["views"][0]["injected_mean"] == 0.0  # the builder keeps view 0 clean
    assert all(v["injected_mean"] > 0 for v in record["views"][1:])
    assert read_image(run / "inconsistency.png").shape[:2] == (4 * 16, 4 * 16)
    # the same pictures again from the command line, elsewhere
    assert export_main(["diagnostics", "--load-dir", str(run), "--output-dir", str(tmp_path / "again"),
                        "--scale", "0.5"]) == 0
    assert (tmp_path / "again" / "attention.png").exists()


def test_diagnostics_of_a_plain_run_is_a_clear_error(tiny_scene, tmp_path, capsys):
    tiny_config("neus", tiny_scene, tmp_path / "run", steps=1).setup().train()
    assert export_main(["diagnostics", "--load-dir", str(tmp_path / "run")]) == 2
    assert "not view-adaptive" in capsys.readouterr().err


@pytest.mark.parametrize("method,phase_fractions", [
    ("va-neus", (0.0, 0.0)),    # fusion
    ("va-ngp", (0.0, 0.0)),
    ("va-neus", (0.0, 1.0)),    # branches alone
])
def test_one_pass_maps_equal_two_separate_renders(method, phase_fractions, tiny_scene, tmp_path):
    """The maps render each view once (own and canonical color from the same samples); that must be
    exactly what two separate renders, own path and novel-view path, give."""
    import torch

    from va_plugin.export.inconsistency import inconsistency_maps
    from va_plugin.export.render import render_view

    trainer = tiny_config(method, tiny_scene, tmp_path / "run", steps=2, **{
        "pipeline.model.field.skip_consistent_scenes": "false", "pipeline.model.field.diagnostics_scale": 0,
        "pipeline.model.field.pretrain_fraction": phase_fractions[0],
        "pipeline.model.field.branch_fraction": phase_fractions[1]}).setup()
    trainer.train()
    field = trainer.model.field
    with torch.no_grad():  # make the branches and the attention matter
        for p in list(field.branches.parameters()) + ([] if field.attention is None
                                                       else list(field.attention.parameters())):
            p.add_(0.05 * torch.randn_like(p))
    maps = inconsistency_maps(trainer.pipeline, scale=1.0)
    assert not field.also_canonical
    cameras = trainer.pipeline.datamanager.cameras
    differs = 0.0
    for view, entry in enumerate(maps):
        own = render_view(trainer.model, cameras, view, as_view=view)
        canonical = render_view(trainer.model, cameras, view)
        assert np.allclose(entry["own"], own, atol=1e-6) and np.allclose(entry["canonical"], canonical, atol=1e-6)
        differs = max(differs, float(np.abs(own - canonical).max()))
    assert differs > 1e-4  # the test would pass vacuously if own and canonical were the same image


def test_failing_diagnostics_warn_and_keep_the_trained_run(tiny_scene, tmp_path, monkeypatch):
    import va_plugin.analysis.diagnostics as diagnostics
    from va_plugin.engine.trainer import list_checkpoints

    def broken(*args, **kwargs):
        raise KeyError("rgb_canonical")

    monkeypatch.setattr(diagnostics, "write_diagnostics", broken)
    trainer = tiny_config("va-neus", tiny_scene, tmp_path / "run", steps=3, **{
        "pipeline.model.field.skip_consistent_scenes": "false"}).setup()
    with pytest.warns(UserWarning, match="diagnostics pictures failed .*va-export diagnostics"):
        trainer.train()
    assert [c.name for c in list_checkpoints(tmp_path / "run")] == ["step-0000003.ckpt"]
