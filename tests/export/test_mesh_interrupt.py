"""Ctrl-C while a mesh is extracted is answered at once: the grid is sampled chunk by chunk in Python, so
the interrupt lands between two chunks, not after the whole grid (and va-recon then says --resume)."""

import os
import signal

import pytest
from conftest import tiny_config

from va_plugin.export.mesh import extract_mesh


def test_ctrl_c_stops_the_grid_at_the_next_chunk(tiny_scene, tmp_path, monkeypatch):
    model = tiny_config("neus", tiny_scene, tmp_path / "run").setup().pipeline.model  # a sphere at setup
    field, calls = model.mesh_field, []

    def interrupted_at_the_first_chunk(points):
        calls.append(len(points))
        if len(calls) == 1:
            os.kill(os.getpid(), signal.SIGINT)
        return field(points)

    monkeypatch.setattr(model, "mesh_field", interrupted_at_the_first_chunk)
    monkeypatch.setattr(model, "mesh_field_lipschitz", None, raising=False)  # the plain grid: many chunks
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            extract_mesh(model, resolution=96, with_color=False)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert len(calls) <= 2  # of the 14 chunks of a 96^3 grid
