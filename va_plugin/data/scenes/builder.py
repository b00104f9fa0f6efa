"""Writing benchmark scenes in the ``transforms.json`` layout.

A scene folder holds ``transforms_train.json`` (the input views), ``transforms_test.json`` (clean
held-out views), ``images/`` (RGBA PNG), ``mesh.ply`` (ground truth, same world frame) and
``scene.json`` (source, rig, inconsistency, seed and measured error sizes).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Dict, List, Optional

import numpy as np

from va_plugin.data.dataparsers.transforms import frames_to_json
from va_plugin.data.images import write_image
from va_plugin.data.scenes.raycast import MeshRenderer
from va_plugin.data.scenes.rig import input_view_ids, syncdreamer_rig
from va_plugin.data.scenes.shapes import get_object, mesh_from_sdf

SCENE_RADIUS = 0.9  # the unit box's corners are at 0.866 from the origin


def build_procedural_scene(out_dir: Path, name: str = "mug", n_views: int = 4, resolution: int = 256,
                           seed: int = 42, mesh_resolution: int = 160,
                           test_views: Optional[List[int]] = None) -> Path:
    """Render a procedural object on the SyncDreamer rig into a scene folder; returns the folder."""
    out_dir = Path(out_dir)
    obj = get_object(name)
    mesh = mesh_from_sdf(obj.sdf, resolution=mesh_resolution)
    renderer = MeshRenderer(mesh, obj.texture)
    cameras = syncdreamer_rig(resolution)
    train_ids = input_view_ids(n_views)
    held_out = [i for i in range(len(cameras)) if i not in train_ids]
    test_ids = held_out if test_views is None else [held_out[i % len(held_out)] for i in test_views]
    (out_dir / "images").mkdir(parents=True, exist_ok=True)
    for split, ids in (("train", train_ids), ("test", test_ids)):
        paths = []
        for i in ids:
            rel = f"images/{split}_{i:03d}.png"
            write_image(out_dir / rel, renderer.render(cameras, i))
            paths.append(rel)
        meta = frames_to_json(cameras.subset(ids), paths, {"scene_radius": SCENE_RADIUS, "rig_views": ids})
        (out_dir / f"transforms_{split}.json").write_text(json.dumps(meta, indent=1))
    mesh.export(out_dir / "mesh.ply")
    info: Dict[str, Any] = {"source": f"procedural:{name}", "description": obj.description, "rig": "syncdreamer",
                            "resolution": resolution, "train_views": train_ids, "test_views": test_ids,
                            "inconsistency": {"kinds": [], "level": 0}, "seed": seed,
                            "mesh": "mesh.ply", "scene_radius": SCENE_RADIUS}
    (out_dir / "scene.json").write_text(json.dumps(info, indent=2))
    return out_dir


def ensure_default_scene(cache_dir: Path, resolution: int = 256) -> Path:
    """The embedded default scene, built on first use into ``cache_dir`` (no download, no shared data)."""
    cache_dir = Path(cache_dir)
    marker = cache_dir / "scene.json"
    if marker.is_file():
        info = json.loads(marker.read_text())
        if info.get("resolution") == resolution:
            return cache_dir
    return build_procedural_scene(cache_dir, "mug", n_views=4, resolution=resolution)
