import json

import pytest
import torch
from conftest import tiny_config

from va_plugin.callbacks import AFTER_STEP, BEFORE_STEP, TrainingCallback
from va_plugin.engine.trainer import atomic_save, list_checkpoints, load_checkpoint, make_adam
from va_plugin.errors import CheckpointError, ConfigError
from va_plugin.registry import discover_methods

METHODS = sorted(discover_methods())


@pytest.mark.parametrize("method", METHODS)
def test_two_iteration_smoke(method, tiny_scene, tmp_path):
    trainer = tiny_config(method, tiny_scene, tmp_path / method, steps=2).setup()
    record = trainer.train()
    assert trainer.step == 2 and record["step"] == 2
    assert all(torch.isfinite(p).all() for p in trainer.model.parameters())
    records = [json.loads(line) for line in (tmp_path / method / "metrics.jsonl").read_text().splitlines()]
    steps = [r for r in records if "loss" in r]  # other lines are events (e.g. phase switches)
    assert [r["step"] for r in steps] == [1, 2]
    assert len(list_checkpoints(tmp_path / method)) == 1


def _params(trainer):
    return {k: v.detach().clone() for k, v in trainer.model.state_dict().items()}


def test_resume_continues_bitwise(tiny_scene, tmp_path):
    full = tiny_config("neus", tiny_scene, tmp_path / "full", steps=6, checkpoint_every=3).setup()
    full.train()

    def interrupt(step, trainer):
        if step == 3:
            raise KeyboardInterrupt

    first = tiny_config("neus", tiny_scene, tmp_path / "cut", steps=6, checkpoint_every=3).setup()
    first.callbacks.append(TrainingCallback(interrupt, BEFORE_STEP))
    with pytest.raises(KeyboardInterrupt):
        first.train()
    assert first.step == 3
    second = tiny_config("neus", tiny_scene, tmp_path / "cut", steps=6, checkpoint_every=3).setup()
    assert second.resume() and second.step == 3
    second.train()
    a, b = _params(full), _params(second)
    assert all(torch.equal(a[k], b[k]) for k in a), "resumed run differs from the uninterrupted one"


def test_a_run_resumed_at_its_last_step_renders_as_the_run_that_trained_it(tiny_scene, tmp_path):
    """Reopening a finished run (``va-demo`` or ``va-train`` again on its folder) runs no step, so the model's
    step schedules must come from the checkpoint, not from step 0."""
    config = dict(steps=8, checkpoint_every=8, **{"pipeline.model.field.coarse_to_fine_fraction": 0.5})
    trained = tiny_config("neus", tiny_scene, tmp_path / "run", **config).setup()
    trained.train()
    reopened = tiny_config("neus", tiny_scene, tmp_path / "run", **config).setup()
    assert reopened.resume() and reopened.step == 8
    assert reopened.model.step == trained.model.step == 7  # the last step run
    assert reopened.model.field.encoding.n_active_levels == trained.model.field.encoding.n_active_levels
    for trainer in (trained, reopened):
        trainer.model.eval()
    with torch.no_grad():
        renders = [trainer.pipeline.evaluate_views(1)[1][0]["rgb"] for trainer in (trained, reopened)]
    assert torch.equal(renders[0], renders[1])


def test_a_checkpoint_with_the_entry_major_hash_table_resumes_bitwise(tiny_scene, tmp_path):
    """A checkpoint written when the hash table (and its Adam moments) was stored ``[entries, F]``
    resumes exactly as one in today's feature-major layout."""
    runs = {}
    for name in ("today", "earlier"):
        first = tiny_config("neus", tiny_scene, tmp_path / name, steps=4, checkpoint_every=2).setup()
        first.callbacks.append(TrainingCallback(lambda step, trainer: step == 2 and _interrupt(), BEFORE_STEP))
        with pytest.raises(KeyboardInterrupt):
            first.train()
        if name == "earlier":
            path = list_checkpoints(tmp_path / name)[-1]
            state = torch.load(path, weights_only=False)
            key = next(k for k in state["model"] if k.endswith("encoding.table"))
            table = state["model"][key]
            state["model"][key] = table.t().contiguous()
            moments = [m for m in state["optimizer"]["state"].values() if m["exp_avg"].shape == table.shape]
            assert len(moments) == 1
            for moment in ("exp_avg", "exp_avg_sq"):
                moments[0][moment] = moments[0][moment].t().contiguous()
            atomic_save(state, path)
        second = tiny_config("neus", tiny_scene, tmp_path / name, steps=4, checkpoint_every=2).setup()
        assert second.resume() and second.step == 2
        second.train()
        runs[name] = _params(second)
    assert all(torch.equal(runs["today"][k], runs["earlier"][k]) for k in runs["today"])


def _interrupt():
    raise KeyboardInterrupt


def test_half_written_checkpoint_falls_back_to_previous(tiny_scene, tmp_path):
    trainer = tiny_config("neus", tiny_scene, tmp_path / "run", steps=2, checkpoint_every=1).setup()
    trainer.train()
    newest = list_checkpoints(tmp_path / "run")[-1]
    newest.write_bytes(newest.read_bytes()[:100])  # as if killed mid-write without the atomic rename
    with pytest.warns(UserWarning, match="unreadable"):
        state = load_checkpoint(tmp_path / "run")
    assert state["step"] == 1


def test_atomic_save_leaves_no_partial_file(tmp_path):
    class Boom:
        def __reduce__(self):
            raise RuntimeError("disk full")

    target = tmp_path / "a.ckpt"
    atomic_save({"ok": 1}, target)
    with pytest.raises(RuntimeError):
        atomic_save({"bad": Boom()}, target)
    assert torch.load(target) == {"ok": 1}


def test_checkpoint_of_another_method_is_refused(tiny_scene, tmp_path):
    trainer = tiny_config("neus", tiny_scene, tmp_path / "run", steps=1).setup()
    trainer.train()
    other = tiny_config("neus", tiny_scene, tmp_path / "run", steps=2).setup()
    other.config.method_name = "something-else"
    with pytest.raises(CheckpointError, match="of method 'neus'"):
        other.resume()


def test_missing_checkpoints_and_bad_config(tmp_path, tiny_scene):
    with pytest.raises(CheckpointError, match="holds no checkpoint"):
        (tmp_path / "empty").mkdir() or load_checkpoint(tmp_path / "empty")
    with pytest.raises(ConfigError, match="max_steps"):
        tiny_config("neus", tiny_scene, tmp_path / "x", steps=0).setup()


def test_nan_batch_is_skipped_with_one_warning(tiny_scene, tmp_path):
    trainer = tiny_config("neus", tiny_scene, tmp_path / "nan", steps=3).setup()
    real = trainer.pipeline.datamanager.next_train

    def poisoned(step):
        rays, batch = real(step)
        if step == 1:
            batch["rgb"] = torch.full_like(batch["rgb"], float("nan"))
        return rays, batch

    trainer.pipeline.datamanager.next_train = poisoned
    with pytest.warns(UserWarning, match="non-finite"):
        trainer.train()
    assert trainer.bad_steps == 1
    assert all(torch.isfinite(p).all() for p in trainer.model.parameters())


def test_callbacks_get_attributes_not_the_trainer_and_return_learning_rate_factors(tiny_scene, tmp_path):
    from va_plugin.callbacks import TrainingCallbackAttributes

    trainer = tiny_config("neus", tiny_scene, tmp_path / "run", steps=2).setup()
    seen = []

    def halve(step, attributes):
        seen.append(attributes)
        return {"fields": 0.5}

    trainer.callbacks.append(TrainingCallback(halve, BEFORE_STEP))
    trainer.run_step()
    assert isinstance(seen[0], TrainingCallbackAttributes) and seen[0].pipeline is trainer.pipeline
    assert seen[0].max_steps == 2 and not hasattr(seen[0], "optimizer")
    lrs = {group["name"]: group["lr"] for group in trainer.optimizer.param_groups}
    factor = trainer.config.scheduler.factor(0, 2)
    assert lrs["fields"] == pytest.approx(trainer.config.optimizers["fields"].lr * factor * 0.5)
    assert trainer.lr_multipliers["fields"] == 0.5


def test_fused_adam_matches_the_plain_update():
    """The trainer's Adam (fused kernel) against torch's per-tensor loop, on two groups with their own
    rates and the trainer's tiny epsilon, over steps whose gradients change sign and scale."""
    torch.manual_seed(0)
    start = [torch.randn(300), torch.randn(7, 5)]
    runs = []
    for fused in (True, False):
        params = [torch.nn.Parameter(t.clone()) for t in start]
        groups = [{"params": [params[0]], "lr": 1e-2, "eps": 1e-15, "weight_decay": 0.0},
                  {"params": [params[1]], "lr": 5e-3, "eps": 1e-15, "weight_decay": 1e-4}]
        opt = make_adam(groups) if fused else torch.optim.Adam(groups)
        if fused:
            assert opt.defaults.get("fused"), "the fused kernel was not taken on CPU"
        gen = torch.Generator().manual_seed(1)
        for step in range(20):
            for p in params:
                p.grad = torch.randn(p.shape, generator=gen) * (10.0 ** (step % 3 - 1))
            opt.step()
        runs.append([p.detach().clone() for p in params])
    for fused, plain, first in zip(runs[0], runs[1], start):
        assert not torch.equal(plain, first)
        assert torch.allclose(fused, plain, rtol=1e-5, atol=1e-6)


def test_schedule_steps_compress_shorter_budgets_and_caps_longer_ones():
    from va_plugin.engine.trainer import TrainerConfig, schedule_steps_of

    assert schedule_steps_of(TrainerConfig(max_steps=4000)) == 4000
    assert schedule_steps_of(TrainerConfig(max_steps=4000, schedule_steps=2000)) == 2000
    assert schedule_steps_of(TrainerConfig(max_steps=500, schedule_steps=2000)) == 500


def test_steps_past_the_schedule_continue_the_shorter_run_at_its_final_rates(tiny_scene, tmp_path):
    """With ``schedule_steps=3`` a 6-step run is, for its first 3 steps, the 3-step run bit for bit (same
    learning rates, grid levels and model schedules); after them every learning rate stays at the
    schedule's final value."""
    short = tiny_config("neus", tiny_scene, tmp_path / "short", steps=3, **{"scheduler.warmup_steps": 1}).setup()
    short.train()
    seen = []

    def record_rates(step, attributes):
        seen.append((step, attributes.schedule_steps, [g["lr"] for g in longer.optimizer.param_groups]))

    longer = tiny_config("neus", tiny_scene, tmp_path / "long", steps=6, checkpoint_every=3,
                         **{"scheduler.warmup_steps": 1, "schedule_steps": 3}).setup()
    assert longer.model.scene.schedule_steps == 3
    longer.callbacks.append(TrainingCallback(record_rates, AFTER_STEP))
    checkpoint_at_3 = {}

    def keep(step, attributes):
        if step == 2:
            checkpoint_at_3.update(_params(longer))

    longer.callbacks.append(TrainingCallback(keep, AFTER_STEP))
    longer.train()
    a = _params(short)
    assert all(torch.equal(a[k], checkpoint_at_3[k]) for k in a), "the first 3 steps differ from the 3-step run"
    final = [longer.config.optimizers[g["name"]].lr * longer.config.scheduler.final_fraction
             for g in longer.optimizer.param_groups]
    assert [h for _, h, _ in seen] == [3] * 6
    for step, _, rates in seen[3:]:
        assert rates == pytest.approx(final), f"step {step}: rates {rates} are not the final ones {final}"
    assert seen[0][2] != pytest.approx(final)


def test_negative_schedule_steps_is_refused(tiny_scene, tmp_path):
    config = tiny_config("neus", tiny_scene, tmp_path, steps=2)
    config.schedule_steps = -5
    with pytest.raises(ConfigError, match="schedule_steps"):
        config.setup()


def test_checkpoint_of_an_earlier_version_loads_without_its_removed_options(tiny_scene, tmp_path, monkeypatch):
    """A run whose config held an option class that has since left the package still loads (the class reads
    back as RemovedOption); a missing class outside the package is still an error."""
    import sys
    import types
    from dataclasses import dataclass

    from va_plugin.api import load_run
    from va_plugin.engine.trainer import RemovedOption, load_checkpoint

    @dataclass
    class GoneOptionConfig:
        strength: float = 0.0

    module = types.ModuleType("va_plugin.gone_option")
    GoneOptionConfig.__module__, GoneOptionConfig.__qualname__ = module.__name__, "GoneOptionConfig"
    module.GoneOptionConfig = GoneOptionConfig
    monkeypatch.setitem(sys.modules, module.__name__, module)
    config = tiny_config("neus", tiny_scene, tmp_path / "run", steps=1)
    config.pipeline.model.gone_option = GoneOptionConfig()
    config.setup().train()
    monkeypatch.delitem(sys.modules, module.__name__)
    state = load_checkpoint(tmp_path / "run")
    assert isinstance(state["config_object"].pipeline.model.gone_option, RemovedOption)
    pipeline, _ = load_run(tmp_path / "run").parts()
    assert pipeline.model is not None
