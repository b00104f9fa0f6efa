"""Shared fixtures: a tiny rendered scene and tiny configs, so every test runs in seconds on 2 cores."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

# One thread: the tests' tensors are tiny, and on a busy machine two OpenMP threads waiting for each other
# made a 32-ray training step 40x slower (12 s instead of 0.3 s for three steps). VA_TEST_THREADS overrides.
torch.set_num_threads(int(os.environ.get("VA_TEST_THREADS", "1")))

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


CLI_TINY = ["--no-progress", "--device", "cpu", "--steps", "1", "--set", "pipeline.datamanager.rays_per_batch=16",
            "--set", "pipeline.model.n_samples=4", "--set", "pipeline.model.n_importance=4"]
"""``va-train`` options of a one-step run with a handful of rays and samples."""


def one_line_error(capsys, code, message):
    """The command exited 2 with one stderr line, ``error: ...`` holding ``message``."""
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0], err


@pytest.fixture(scope="session")
def tiny_scene(tmp_path_factory) -> Path:
    """The default procedural object on the SyncDreamer rig at 24 x 24 px (4 inputs + held-out views);
    ``$VA_TEST_SCENE``: such a scene built beforehand (a machine without open3d, which renders it)."""
    if os.environ.get("VA_TEST_SCENE"):
        return Path(os.environ["VA_TEST_SCENE"])
    from va_plugin.bench.scenes.builder import build_procedural_scene

    return build_procedural_scene(tmp_path_factory.mktemp("scene"), "mug", n_views=4, resolution=24)


def tiny_config(method: str, scene: Path, out: Path, steps: int = 2, **overrides):
    """A method's config shrunk to a handful of rays and samples."""
    from va_plugin.config import apply_override
    from va_plugin.registry import get_method

    config = get_method(method).make_config()
    config.pipeline.datamanager.dataparser.data = Path(scene)
    config.output_dir = Path(out)
    config.max_steps = steps
    config.progress = False
    config.checkpoint_every = max(1, steps)
    config.log_every = 1
    config.device = "cpu"
    shrink = {"pipeline.datamanager.rays_per_batch": 32}
    model = config.pipeline.model
    for name, value in (("n_samples", 8), ("n_importance", 8), ("eval_chunk", 256), ("crossings_rays", 8),
                        ("crossings_samples", 16)):
        if hasattr(model, name):
            shrink[f"pipeline.model.{name}"] = value
    shrink.update(overrides)
    for key, value in shrink.items():
        apply_override(config, f"{key}={value}")
    return config


def tiny_trained_run(tmp_path_factory, resolution: int = 32, steps: int = 2, with_mesh: bool = True) -> Path:
    """A ``neus`` run folder trained ``steps`` steps on the mug at ``resolution`` px (its geometric
    initialisation is a sphere: a surface to export). ``with_mesh=False`` drops the ground-truth mesh from
    scene.json, so va-eval skips the geometry metrics (a 100k-sample Chamfer: a minute on a busy machine)."""
    import json

    from va_plugin.bench.scenes.builder import build_procedural_scene

    scene = build_procedural_scene(tmp_path_factory.mktemp("scene"), "mug", n_views=4, resolution=resolution)
    if not with_mesh:
        info = json.loads((scene / "scene.json").read_text())
        info.pop("mesh")
        (scene / "scene.json").write_text(json.dumps(info))
    out = tmp_path_factory.mktemp("run")
    tiny_config("neus", scene, out, steps=steps).setup().train()
    return out


@pytest.fixture
def no_env_methods(monkeypatch):
    monkeypatch.delenv("VA_PLUGIN_METHODS", raising=False)
    return os.environ


# -- a small object on the generators' rigs ------------------------------------------------------------
def toy_object():
    """A box with a ball on one corner (no mirror symmetry about the vertical planes), inside the unit box."""
    import trimesh

    box = trimesh.creation.box(extents=(0.6, 0.4, 0.5))
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.18)
    ball.apply_translation((0.25, 0.2, 0.2))
    return trimesh.util.concatenate([box, ball])


def toy_albedo(points):
    """Saturated colors far from white and gray, so a color key separates them cleanly."""
    import numpy as np

    return np.stack([0.6 + 0.3 * np.sign(points[:, 0]), 0.15 + 0.3 * (points[:, 2] > 0), np.full(len(points), 0.1)], -1)


def render_views(renderer, cameras, background):
    """RGB views composited on ``background`` and their alpha ``[n, t, t]``."""
    import numpy as np

    rgba = np.stack([renderer.render(cameras, k) for k in range(len(cameras))])
    rgb = rgba[..., :3] * rgba[..., 3:] + np.asarray(background, np.float32) * (1 - rgba[..., 3:])
    return rgb, rgba[..., 3]


def write_syncdreamer_strip(path: Path, tile: int = 32, alpha: bool = False) -> Path:
    """The toy object on SyncDreamer's rig, written as its output strip (on white; RGBA with ``alpha``)."""
    import numpy as np

    from va_plugin.data import rigs
    from va_plugin.data.images import write_image
    from va_plugin.raycast import MeshRenderer, position_albedo

    renderer = MeshRenderer(toy_object(), position_albedo(toy_albedo))
    rgb, a = render_views(renderer, rigs.syncdreamer_rig(tile, pixel_offset=0.5), (1.0, 1.0, 1.0))
    image = np.concatenate(list(np.concatenate([rgb, a[..., None]], -1) if alpha else rgb), axis=1)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, image)
    return path
