"""Per-view camera refinement: Rodrigues against hand values and matrix_exp, the frozen and novel
views untouched, finite gradients at zero, and the corrections training inside neus."""

import json
import math

import pytest
import torch

from conftest import tiny_config
from per_view_checks import assert_one_step_trains_unfrozen_views
from va_plugin.errors import ConfigError
from va_plugin.model_components.camera_opt import MAX_ROTATION_RAD, CameraOptimizerConfig, rotation_matrix
from va_plugin.rays import RayBundle


def _skew(v):
    x, y, z = v.tolist()
    return torch.tensor([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]], dtype=torch.float64)


def test_rotation_matrix_hand_computed_and_against_matrix_exp():
    quarter = rotation_matrix(torch.tensor([0.0, 0.0, math.pi / 2]))
    assert torch.allclose(quarter, torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), atol=1e-6)
    for v in ([0.3, -0.2, 0.1], [1e-4, 2e-4, -1e-4], [0.0, 0.0, 0.0], [1e-3, 0.0, 0.0]):
        rotvec = torch.tensor(v, dtype=torch.float64)
        assert torch.allclose(rotation_matrix(rotvec), torch.linalg.matrix_exp(_skew(rotvec)), atol=1e-12), v


def test_rotation_gradient_is_finite_and_right_at_zero():
    rotvec = torch.zeros(3, requires_grad=True)
    point = torch.tensor([1.0, 2.0, 3.0])
    (rotation_matrix(rotvec) @ point).sum().backward()
    # d(R p)/dw at w = 0 is -[p]_x, so the gradient of sum(R p) is (1,1,1) @ -[p]_x = p x (1,1,1)
    assert torch.allclose(rotvec.grad, torch.linalg.cross(point, torch.ones(3)), atol=1e-6)


def test_apply_leaves_frozen_and_novel_views_alone():
    optimizer = CameraOptimizerConfig(mode="SE3").setup(num_views=3)
    with torch.no_grad():
        optimizer.correction.copy_(torch.tensor([[0.1, 0.0, 0.0, 0.1, 0.0, 0.0]] * 3))
    origins = torch.tensor([[0.0, 1.0, 0.0]] * 4)
    directions = torch.tensor([[0.0, -1.0, 0.0]] * 4)
    rays = optimizer.apply(RayBundle(origins, directions, torch.tensor([0, 1, 2, -1])))
    assert torch.equal(rays.origins[[0, 3]], origins[[0, 3]]) and torch.equal(rays.directions[[0, 3]], directions[[0, 3]])
    expected = torch.tensor([0.1, math.cos(0.1), math.sin(0.1)])  # rotated 0.1 rad about x, shifted along x
    assert torch.allclose(rays.origins[1], expected, atol=1e-6) and torch.allclose(rays.origins[2], expected, atol=1e-6)
    assert torch.allclose(rays.directions[1].norm(), torch.tensor(1.0))
    # SO3 keeps the translation at zero whatever the parameter holds
    so3 = CameraOptimizerConfig(mode="SO3").setup(num_views=3)
    with torch.no_grad():
        so3.correction.copy_(optimizer.correction)
    assert torch.allclose(so3.apply(RayBundle(origins, directions, torch.tensor([1, 1, 1, 1]))).origins[0],
                          torch.tensor([0.0, math.cos(0.1), math.sin(0.1)]), atol=1e-6)
    summary = optimizer.summary()
    assert summary["rotation_deg"][0] == 0.0 and summary["max_rotation_deg"] == pytest.approx(math.degrees(0.1), abs=1e-3)
    assert summary["max_translation"] == pytest.approx(0.1, abs=1e-5)


def test_a_diverging_correction_is_clamped_and_the_penalty_counts_trained_views_only():
    optimizer = CameraOptimizerConfig(mode="SE3", penalty_weight=2.0).setup(num_views=2)
    with torch.no_grad():
        optimizer.correction.fill_(100.0)
    rotations, translations = optimizer.corrections()
    angle = torch.acos(((rotations[1].trace() - 1) / 2).clamp(-1, 1))
    assert float(angle.detach()) == pytest.approx(MAX_ROTATION_RAD, abs=1e-4) and torch.isfinite(translations).all()
    assert float(optimizer.loss().detach()) == pytest.approx(2.0 * 6 * 100.0 ** 2 / 6)  # view 0 frozen: 6 trained entries


def test_bad_mode_is_a_config_error():
    with pytest.raises(ConfigError, match="camera_opt.mode"):
        CameraOptimizerConfig(mode="se3x").setup(num_views=2)


def test_neus_trains_the_corrections_of_unfrozen_views(tiny_scene, tmp_path):
    torch.manual_seed(0)
    config = tiny_config("neus", tiny_scene, tmp_path / "run", steps=3,
                         **{"pipeline.model.camera_opt.mode": "SE3"})
    trainer = config.setup()
    model = trainer.model
    assert "camera_opt" in model.get_param_groups()
    assert_one_step_trains_unfrozen_views(trainer, "camera_opt", model.camera_optimizer.correction)
    before = model.camera_optimizer.correction.detach().clone()
    record = trainer.train()
    moved = (model.camera_optimizer.correction.detach() - before).abs().sum(-1)
    assert moved[0] == 0 and bool((moved[1:] > 0).all()) and record["camera_max_deg"] > 0.0
    written = json.loads((tmp_path / "run" / "camera_refinement.json").read_text())
    assert written["rotation_deg"][0] == 0.0 and len(written["rotation_deg"]) == 4
    # off (the default): no parameters, no state-dict entry, no loss term
    plain = tiny_config("neus", tiny_scene, tmp_path / "plain").setup().model
    assert plain.camera_optimizer is None and not any("camera" in k for k in plain.state_dict())


def test_train_until_freezes_the_corrections_and_drops_their_penalty(tiny_scene, tmp_path):
    """``train_until=0.5`` of 4 steps: the corrections move in steps 0-1 and stay put in steps 2-3 (no
    gradient reaches them, their penalty is 0); the summary keeps the rotation vectors."""
    with pytest.raises(ConfigError, match="train_until"):
        CameraOptimizerConfig(mode="SO3", train_until=1.5).setup(num_views=2)
    optimizer = CameraOptimizerConfig(mode="SO3", penalty_weight=1.0, train_until=0.5).setup(num_views=2)
    with torch.no_grad():
        optimizer.correction.fill_(0.1)
    optimizer.set_step(1, 4)
    assert not optimizer.frozen and float(optimizer.loss().detach()) == pytest.approx(0.01)
    optimizer.set_step(2, 4)
    assert optimizer.frozen and float(optimizer.loss()) == 0.0
    rotations, _ = optimizer.corrections()
    assert not rotations.requires_grad and torch.allclose(rotations[1], rotation_matrix(torch.full((3,), 0.1)))
    assert optimizer.summary()["rotation_vector"][1] == pytest.approx([0.1, 0.1, 0.1])

    torch.manual_seed(0)
    config = tiny_config("neus", tiny_scene, tmp_path / "run", steps=4,
                         **{"pipeline.model.camera_opt.mode": "SO3", "pipeline.model.camera_opt.train_until": 0.5})
    trainer = config.setup()
    correction = trainer.model.camera_optimizer.correction
    after = []
    for _ in range(4):
        trainer.run_step()
        after.append(correction.detach().clone())
    assert (after[1] - torch.zeros_like(after[1])).abs().sum() > 0  # steps 0-1 train it
    assert torch.equal(after[1], after[2]) and torch.equal(after[2], after[3])  # steps 2-3 leave it alone


def test_the_surface_moves_with_the_camera_in_the_gradient(tiny_scene, tmp_path):
    """The rendering pass evaluates the SDF at sample points detached from the rays (the field's gradient
    is computed there); a camera correction must still see how moving its rays moves them through the
    SDF. A translation of the camera changes nothing else (directions stay), so without that first-order
    path its gradient was exactly zero."""
    torch.manual_seed(0)
    config = tiny_config("neus", tiny_scene, tmp_path / "run", steps=2, **{"pipeline.model.camera_opt.mode": "SE3"})
    trainer = config.setup()
    model = trainer.model
    with torch.no_grad():
        model.camera_optimizer.correction[:, 3:] = 0.01  # off zero: the penalty's own gradient is then 2 w x
    rays, batch = trainer.pipeline.datamanager.next_train(0)
    loss = model.get_loss_dict(model.get_outputs(rays), batch)
    sum(v for k, v in loss.items() if k != "camera_opt").backward()
    translation_grad = model.camera_optimizer.correction.grad[:, 3:]
    assert torch.isfinite(translation_grad).all()
    assert translation_grad[0].abs().sum() == 0 and bool((translation_grad[1:].abs().sum(-1) > 0).all())
