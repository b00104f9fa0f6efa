"""The stopping rule: the surface-change measure against a plain count, and the trainer ending (or, recording
only, not ending) a run on it."""

import json
import math
from types import SimpleNamespace

import pytest
import torch
from torch import nn

from conftest import tiny_config
from va_plugin.engine.stopping import StopConfig, SurfaceSettling
from va_plugin.engine.trainer import list_checkpoints, load_checkpoint
from va_plugin.errors import ConfigError


class Ball(nn.Module):
    """A mesh field whose surface is a sphere of radius ``r`` (negative inside)."""

    def __init__(self, r: float) -> None:
        super().__init__()
        self.r = nn.Parameter(torch.tensor(r))
        self.scene = SimpleNamespace(scene_radius=1.0)

    def mesh_field(self, points):
        return points.norm(dim=-1) - self.r


def count_inside(r: float, grid: int) -> torch.Tensor:
    """The plain reference: grid points over [-1, 1]^3 with |p| < r (and inside the unit sphere)."""
    axis = [-1.0 + 2.0 * i / (grid - 1) for i in range(grid)]
    return torch.tensor([[[(x * x + y * y + z * z) ** 0.5 < min(r, 1.0) for z in axis] for y in axis] for x in axis])


def test_change_is_the_share_of_inside_points_that_crossed_the_surface():
    rule = SurfaceSettling(StopConfig(enabled=True, grid=9, tolerance=0.2, patience=2, check_every=10), horizon=100)
    ball = Ball(0.5)
    first = rule.check(ball)
    assert math.isnan(first["change"]) and first["settled"] == 0
    ball.r.data.fill_(0.8)
    expected = float((count_inside(0.8, 9) ^ count_inside(0.5, 9)).sum()) / float(count_inside(0.8, 9).sum())
    second = rule.check(ball)
    assert second["change"] == pytest.approx(expected) and expected > 0.2 and second["settled"] == 0
    assert rule.check(ball) == {"change": 0.0, "settled": 1} and not rule.stop
    assert rule.check(ball)["settled"] == 2 and rule.stop


def test_checks_start_at_the_share_of_the_schedule_and_come_every_few_steps():
    rule = SurfaceSettling(StopConfig(enabled=True, start=0.5, check_every=10), horizon=100)
    assert [s for s in range(101) if rule.due(s)] == [50, 60, 70, 80, 90, 100]
    assert not any(SurfaceSettling(StopConfig(), horizon=100).due(s) for s in range(101))  # off by default
    with pytest.raises(ConfigError, match="tolerance"):
        SurfaceSettling(StopConfig(enabled=True, tolerance=2.0), horizon=100)


def _losses(run_dir):
    return [r["loss"] for r in map(json.loads, (run_dir / "metrics.jsonl").read_text().splitlines()) if "loss" in r]


def test_the_trainer_stops_a_settled_run_and_a_resume_keeps_it_stopped(tiny_scene, tmp_path):
    stop = {"stop.enabled": True, "stop.start": 0.2, "stop.check_every": 2, "stop.tolerance": 1.0, "stop.grid": 16}
    trainer = tiny_config("neus", tiny_scene, tmp_path / "run", steps=20, checkpoint_every=100, **stop).setup()
    trainer.train()
    # checks at steps 4, 6, 8: the first sets the baseline, the next two are settled (tolerance 1)
    assert trainer.step == 8 and trainer.stopped
    state = load_checkpoint(tmp_path / "run")
    assert state["step"] == 8 and state["stopped"]
    records = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records if "stop_change" in r] == [4, 6, 8]
    assert any(r.get("stopped") for r in records)
    again = tiny_config("neus", tiny_scene, tmp_path / "run", steps=20, checkpoint_every=100, **stop).setup()
    assert again.resume() and again.stopped
    again.train()
    assert again.step == 8


def test_recording_only_trains_the_same_steps_and_keeps_a_checkpoint_per_check(tiny_scene, tmp_path):
    plain = tiny_config("neus", tiny_scene, tmp_path / "plain", steps=8).setup()
    plain.train()
    record = {"stop.record_only": True, "stop.start": 0.25, "stop.check_every": 2, "stop.tolerance": 1.0,
              "stop.grid": 16}
    recorded = tiny_config("neus", tiny_scene, tmp_path / "rec", steps=8, **record).setup()
    recorded.train()
    assert recorded.step == 8 and not recorded.stopped
    assert _losses(tmp_path / "plain") == _losses(tmp_path / "rec")  # the checks draw no random numbers
    kept = sorted(p.name for p in (tmp_path / "rec" / "settling").glob("*.ckpt"))
    assert kept == ["step-0000002.ckpt", "step-0000004.ckpt", "step-0000006.ckpt", "step-0000008.ckpt"]
    assert len(list_checkpoints(tmp_path / "rec")) == 1
