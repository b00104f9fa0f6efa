"""Smoke test of benchmarks/bench_sdf_gradient.py: one timed step per mode on the tiny scene."""

import argparse

import pytest
import torch

from bench_scripts import load_script


@pytest.fixture(scope="module")
def bench():
    return load_script("bench_sdf_gradient")


def test_both_modes_time_the_same_step(bench, tiny_scene, tmp_path, monkeypatch):
    monkeypatch.setattr(torch.autograd, "grad", torch.autograd.grad)  # the worker wraps it; put it back afterwards
    small = ["pipeline.datamanager.rays_per_batch=32", "pipeline.model.n_samples=8", "pipeline.model.n_importance=8"]
    args = argparse.Namespace(steps=1, threads=1, work=tmp_path / "work", load=None, data=tiny_scene, overrides=small)
    rows = {mode: bench.worker(mode, args) for mode in bench.MODES}
    for mode, (row,) in rows.items():
        assert set(bench.STAGES) <= set(row) and row["step_cpu"] > 0 and row["sdf_and_gradient"] > 0, mode
        assert row["minor_page_faults"] >= 0
    # the same state and batch in both processes: the same loss, to float rounding
    assert rows["analytic"][0]["loss"] == pytest.approx(rows["autograd"][0]["loss"], rel=1e-5)
