"""bench_camera_recovery.py: the injected orbit error as a rotation about the origin, and the share a
learned correction recovers, against hand values (an azimuth error is a turn about world z)."""

from __future__ import annotations

import json
import math

import pytest
import torch
from bench_scripts import load_script


@pytest.fixture(scope="module")
def recovery():
    return load_script("bench_camera_recovery")


def _run(tmp_path, learned_z):
    scene = tmp_path / "scene"
    scene.mkdir()
    per_view = [{"view": 0, "perturbed": False},
                {"view": 4, "perturbed": True, "pose_error_deg": {"azimuth": 2.0, "elevation": 0.0, "roll": 0.0}}]
    (scene / "scene.json").write_text(json.dumps({"resolution": 32, "train_views": [0, 4],
                                                  "inconsistency": {"per_view": per_view}}))
    run = tmp_path / f"run{learned_z}"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"pipeline": {"datamanager": {"dataparser": {"data": str(scene)}}}}))
    rotvec = [[0.0, 0.0, 0.0], [0.0, 0.0, math.radians(learned_z)]]
    (run / "camera_refinement.json").write_text(json.dumps({"rotation_vector": rotvec}))
    return run


def test_an_azimuth_error_is_a_turn_about_z(recovery, tmp_path):
    truth = recovery.true_corrections(_run(tmp_path, 0.0).parent / "scene")
    angle = math.radians(2.0)
    expected = torch.tensor([[math.cos(angle), -math.sin(angle), 0.0], [math.sin(angle), math.cos(angle), 0.0],
                             [0.0, 0.0, 1.0]], dtype=torch.float64)
    assert torch.allclose(truth[4], expected, atol=1e-6) and torch.allclose(truth[0], torch.eye(3, dtype=torch.float64))


@pytest.mark.parametrize("learned, left, recovered", [(2.0, 0.0, 1.0), (0.0, 2.0, 0.0), (1.0, 1.0, 0.5),
                                                     (4.0, 2.0, 0.0), (-1.0, 3.0, -0.5)])
def test_share_recovered(recovery, tmp_path, learned, left, recovered):
    result = recovery.recovery(_run(tmp_path, learned))
    view = result["views"][1]
    assert view["injected_deg"] == pytest.approx(2.0, abs=1e-3) and view["left_deg"] == pytest.approx(left, abs=2e-3)
    assert view["recovered"] == pytest.approx(recovered, abs=2e-3) and result["views"][0]["recovered"] is None


def test_a_run_without_refinement_is_one_error_line(recovery, tmp_path, capsys):
    assert recovery.main([str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("error: ")
