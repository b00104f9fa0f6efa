"""Google Scanned Objects prepared on the SyncDreamer rig (``../shared/data/gso``).

Each ``<root>/<object>/`` holds ``000.png``-``015.png`` (256x256 RGBA renders, view k at azimuth
k * 22.5 deg) and ``model.obj``; ``<root>/alignment.json`` gives the angle ``a`` about +z for each object:
normalise the mesh (largest bounding-box side 1, box centred at the origin), then rotate by ``R_z(-a)``
to land in the renders' frame. There is no texture: the renders are the only appearance.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import trimesh

from va_plugin.bench.scenes.meshfile import normalise_vertices
from va_plugin.bench.scenes.rig import RIG_VIEWS
from va_plugin.cameras import Cameras
from va_plugin.data.images import read_image
from va_plugin.errors import DataError
from va_plugin.raycast import MeshRenderer

GSO_RESOLUTION = 256


def check_root(root: Path) -> Path:
    """The GSO folder, or a DataError naming the missing path."""
    root = Path(root)
    if not (root / "alignment.json").is_file():
        raise DataError(f"GSO data root not found (no alignment.json): {root}; pass --data-root")
    return root


def list_objects(root: Path) -> list[str]:
    """Names of the objects under ``root`` that have a mesh."""
    root = check_root(root)
    return sorted(p.name for p in root.iterdir() if (p / "model.obj").is_file())


def object_dir(root: Path, name: str) -> Path:
    folder = check_root(root) / name
    if not (folder / "model.obj").is_file():
        raise DataError(f"no GSO object {name!r} in {root}; known: {', '.join(list_objects(root))}")
    return folder


def alignment_angle(root: Path, name: str) -> float:
    """Degrees about +z from the normalised mesh to the renders' frame (the mesh is turned by minus this)."""
    table = json.loads((check_root(root) / "alignment.json").read_text())
    if name not in table:
        raise DataError(f"{root / 'alignment.json'} has no entry for {name!r}")
    return float(table[name])


def load_mesh(root: Path, name: str) -> trimesh.Trimesh:
    """The object's mesh in the renders' world frame (welded, so its surface is closed where the scan is)."""
    path = object_dir(root, name) / "model.obj"
    raw = trimesh.load(str(path), force="mesh", process=False)
    a = np.radians(-alignment_angle(root, name))
    rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    vertices = normalise_vertices(np.asarray(raw.vertices, dtype=np.float64)) @ rz.T
    return trimesh.Trimesh(vertices, raw.faces, process=True)


def resize_rgba(image: np.ndarray, resolution: int) -> np.ndarray:
    """Area-resample an RGBA image ``[H, W, 4]`` with premultiplied color (no dark fringes)."""
    if image.shape[0] == resolution and image.shape[1] == resolution:
        return image
    premultiplied = np.concatenate([image[:, :, :3] * image[:, :, 3:], image[:, :, 3:]], -1)
    out = cv2.resize(premultiplied, (resolution, resolution), interpolation=cv2.INTER_AREA)
    alpha = out[:, :, 3:]
    rgb = np.where(alpha > 0, out[:, :, :3] / np.maximum(alpha, 1e-6), 0.0)
    return np.concatenate([np.clip(rgb, 0.0, 1.0), alpha], -1).astype(np.float32)


def load_renders(root: Path, name: str, resolution: int = GSO_RESOLUTION) -> np.ndarray:
    """The 16 rig renders as straight-alpha RGBA ``[16, resolution, resolution, 4]`` float32."""
    folder = object_dir(root, name)
    images = []
    for k in range(RIG_VIEWS):
        image = read_image(folder / f"{k:03d}.png")
        if image.shape[2] != 4:
            raise DataError(f"{folder / f'{k:03d}.png'} has no alpha channel")
        images.append(resize_rgba(image, resolution))
    return np.stack(images)


def silhouette_iou(mesh: trimesh.Trimesh, cameras: Cameras, alphas: np.ndarray) -> list[float]:
    """IoU per view between the mesh's projected silhouette and ``alpha > 0.5`` (``alphas [n, H, W]``):
    the check that mesh, renders and rig conventions agree."""
    renderer = MeshRenderer(mesh, lambda hits: np.zeros((len(hits.points), 3), np.float32))
    scores = []
    for k in range(len(cameras)):
        silhouette = np.isfinite(renderer.depth(cameras, k))
        mask = alphas[k] > 0.5
        scores.append(float((silhouette & mask).sum() / max((silhouette | mask).sum(), 1)))
    return scores
