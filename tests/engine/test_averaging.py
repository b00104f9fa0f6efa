"""Weight averaging: the running mean against hand values, and a run that ends with the mean of its last
steps' parameters, bitwise across an interrupt."""

import pytest
import torch
from conftest import tiny_config
from torch import nn

from va_plugin.callbacks import AFTER_STEP, BEFORE_STEP, TrainingCallback
from va_plugin.engine.averaging import WeightAverage
from va_plugin.errors import ConfigError


def test_running_mean_matches_hand_values_and_skips_steps_before_start():
    p = nn.Parameter(torch.tensor([0.0, 10.0]))
    average = WeightAverage([p], start=1)
    for step, value in enumerate(([100.0, 100.0], [1.0, 2.0], [3.0, 4.0], [5.0, 9.0]), 1):
        p.data = torch.tensor(value)
        average.update(step)  # step 1 is not after start: left out
    assert average.count == 3
    assert average.apply()
    assert torch.allclose(p.data, torch.tensor([3.0, 5.0]))


def test_state_round_trips_and_a_mismatched_state_is_refused():
    p = nn.Parameter(torch.ones(3))
    average = WeightAverage([p], start=0)
    average.update(1)
    other = WeightAverage([nn.Parameter(torch.zeros(3))], start=0)
    other.load_state_dict(average.state_dict())
    assert other.count == 1 and torch.equal(other.mean[0], torch.ones(3))
    assert not WeightAverage([p], start=0).apply()  # nothing averaged yet: parameters untouched
    with pytest.raises(ValueError, match="do not fit"):
        WeightAverage([nn.Parameter(torch.zeros(4))], start=0).load_state_dict(average.state_dict())


def _float_params(trainer):
    return [p.detach().clone() for p in trainer.model.parameters()]


def test_a_run_ends_with_the_mean_of_its_last_steps_and_resumes_bitwise(tiny_scene, tmp_path):
    options = dict(steps=6, checkpoint_every=2, average_fraction=0.5)  # the last 3 steps
    seen, after = [], []
    full = tiny_config("neus", tiny_scene, tmp_path / "full", **options).setup()
    update = full.average.update

    def recording(done):  # called after each optimizer step: seen[k] are the weights after step k + 1
        seen.append(_float_params(full))
        update(done)

    full.average.update = recording
    full.callbacks.append(TrainingCallback(lambda step, trainer: after.append(_float_params(full)), AFTER_STEP))
    full.train()
    expected = [torch.stack([s[i] for s in seen[3:]]).mean(0) for i in range(len(seen[0]))]
    final = _float_params(full)
    assert len(seen) == 6 and all(torch.allclose(f, e, atol=1e-6) for f, e in zip(final, expected))
    assert not all(torch.equal(f, s) for f, s in zip(final, seen[-1]))  # not the last step's weights
    # the last step's after-step callbacks (the diagnostics pictures) already see the averaged weights
    assert all(torch.equal(f, a) for f, a in zip(final, after[-1]))

    def interrupt(step, trainer):
        if step == 5:
            raise KeyboardInterrupt  # aborts step 6: the run resumes from step 4, one step into the mean

    cut = tiny_config("neus", tiny_scene, tmp_path / "cut", **options).setup()
    cut.callbacks.append(TrainingCallback(interrupt, BEFORE_STEP))
    with pytest.raises(KeyboardInterrupt):
        cut.train()
    resumed = tiny_config("neus", tiny_scene, tmp_path / "cut", **options).setup()
    assert resumed.resume() and resumed.step == 4
    resumed.train()
    assert all(torch.equal(a, b) for a, b in zip(final, _float_params(resumed)))


def test_average_fraction_outside_its_range_is_refused(tiny_scene, tmp_path):
    for value in (-0.1, 1.0):
        with pytest.raises(ConfigError, match="average_fraction"):
            tiny_config("neus", tiny_scene, tmp_path, average_fraction=value).setup()
