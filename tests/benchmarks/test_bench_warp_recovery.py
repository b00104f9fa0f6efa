"""bench_warp_recovery.py: the ideal shift undoes a GSO scene's injected warp and pose error, the grid
basis matches the warp module's own reading, and bad input is one error line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from bench_scripts import load_script

from va_plugin.data.images import read_image
from va_plugin.data.scenes.builder import build_scene
from va_plugin.model_components.view_warp import ViewWarpConfig, sample_bilinear

GSO_ROOT = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "gso"
needs_gso = pytest.mark.skipif(not (GSO_ROOT / "alignment.json").is_file(), reason=f"GSO data absent: {GSO_ROOT}")


@pytest.fixture(scope="module")
def recovery():
    return load_script("bench_warp_recovery")


def test_grid_basis_matches_the_warp_module(recovery):
    torch.manual_seed(0)
    module = ViewWarpConfig(enabled=True, grid=4, frozen_views=()).setup(num_views=1)
    with torch.no_grad():
        module.correction.uniform_(-0.01, 0.01)
    h, w = 21, 17
    rows, cols = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    rows, cols = rows.reshape(-1), cols.reshape(-1)
    shifts = module.shifts(torch.zeros(len(rows), dtype=torch.long), torch.from_numpy(rows), torch.from_numpy(cols), h, w)
    grids = module.correction.detach().reshape(2, 16).T.double().numpy() * max(h, w)  # [16, 2] pixels
    basis = recovery.bilinear_basis(4, h, w, rows.astype(np.float64), cols.astype(np.float64))
    assert np.allclose(basis.sum(-1), 1.0)
    assert np.allclose(basis @ grids, shifts.detach().double().numpy(), atol=1e-5)


@needs_gso
def test_the_ideal_shift_undoes_the_injected_warp_and_pose(recovery, tmp_path):
    scene = build_scene(tmp_path / "alarm", "gso:alarm", level=3, resolution=128, kinds="geometric,pose",
                        data_root=GSO_ROOT)
    info = json.loads((scene / "scene.json").read_text())
    ideal = recovery.ideal_shifts(scene, info)
    assert sorted(ideal) == [4, 8, 12]  # view 0 is clean
    for view, shift in ideal.items():
        perturbed = torch.from_numpy(read_image(scene / f"images/train_{view:03d}.png"))[None]
        clean = read_image(scene / f"images/clean_{view:03d}.png")
        rows, cols = np.mgrid[0:128, 0:128].reshape(2, -1)
        at = lambda dr, dc: sample_bilinear(perturbed, torch.zeros(len(rows), dtype=torch.long),  # noqa: E731
                                            torch.from_numpy(rows + dr).float(), torch.from_numpy(cols + dc).float())
        plain = at(0, 0).numpy().reshape(128, 128, -1)
        undone = at(shift[..., 1].reshape(-1), shift[..., 0].reshape(-1)).numpy().reshape(128, 128, -1)
        error = lambda image: float(np.abs(image[..., 3] - clean[..., 3]).mean())  # noqa: E731  silhouettes
        assert np.sqrt((shift ** 2).sum(-1)).mean() > 0.8  # level 3 moves a 128-px view by one to two pixels
        assert error(undone) < 0.6 * error(plain), (view, error(undone), error(plain))
    # a fresh warp registered against the clean renders finds much of the ideal shift
    registered = recovery.register_against_clean(scene)
    assert registered["mean_along"] > 0.5 and registered["mean_left_px"] < 0.8 * registered["mean_injected_px"], registered


def test_a_folder_that_is_not_a_warp_run_is_one_error_line(recovery, tmp_path, capsys):
    assert recovery.main([str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("error: ")
