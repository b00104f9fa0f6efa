"""Procedural objects: signed distance functions meshed by marching cubes, and albedo textures.

Every object fits in the box [-0.5, 0.5]^3 (SyncDreamer's normalisation), z up.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Dict

import numpy as np
import trimesh

from va_plugin.errors import ConfigError

SDF = Callable[[np.ndarray], np.ndarray]
Texture = Callable[[np.ndarray], np.ndarray]


def _length(v: np.ndarray) -> np.ndarray:
    return np.sqrt((v * v).sum(-1))


def sd_torus(p: np.ndarray, major: float, minor: float) -> np.ndarray:
    """Torus around the z axis."""
    q = np.stack([_length(p[:, :2]) - major, p[:, 2]], -1)
    return _length(q) - minor


def sd_capped_cylinder(p: np.ndarray, radius: float, half_height: float) -> np.ndarray:
    d = np.stack([_length(p[:, :2]) - radius, np.abs(p[:, 2]) - half_height], -1)
    return np.minimum(d.max(-1), 0.0) + _length(np.maximum(d, 0.0))


def sd_box(p: np.ndarray, half: np.ndarray) -> np.ndarray:
    q = np.abs(p) - half
    return _length(np.maximum(q, 0.0)) + np.minimum(q.max(-1), 0.0)


def mug_sdf(p: np.ndarray) -> np.ndarray:
    """A mug: a hollow cylinder (a concavity) with a torus handle (genus 1)."""
    body = sd_capped_cylinder(p - [0.0, -0.06, 0.0], 0.26, 0.3)
    hollow = sd_capped_cylinder(p - [0.0, -0.06, 0.08], 0.21, 0.3)
    cup = np.maximum(body, -hollow)
    ring = p - [0.0, 0.24, 0.0]
    handle = sd_torus(ring[:, [1, 2, 0]], 0.14, 0.045)  # a ring in the y-z plane
    handle = np.maximum(handle, -(ring[:, 1]))  # keep the outer half of the ring
    return np.minimum(cup, handle)


def mug_texture(p: np.ndarray) -> np.ndarray:
    """Red/cream horizontal bands on the body, a blue checker on the rim, a dark handle."""
    angle = np.arctan2(p[:, 1] + 0.06, p[:, 0])
    bands = (np.floor((p[:, 2] + 0.5) * 10.0) % 2).astype(np.float32)
    checker = ((np.floor(angle * 8 / np.pi) + np.floor((p[:, 2] + 0.5) * 20)) % 2).astype(np.float32)
    red, cream, blue = np.array([0.8, 0.15, 0.1]), np.array([0.95, 0.9, 0.75]), np.array([0.15, 0.3, 0.8])
    color = bands[:, None] * red + (1 - bands[:, None]) * cream
    rim = (p[:, 2] > 0.2)[:, None]
    color = np.where(rim, checker[:, None] * blue + (1 - checker[:, None]) * cream, color)
    handle = (p[:, 1] > 0.22)[:, None]
    return np.where(handle, np.array([0.2, 0.2, 0.25]), color).astype(np.float32)


@dataclass
class ProceduralObject:
    name: str
    description: str
    sdf: SDF
    texture: Texture


OBJECTS: Dict[str, ProceduralObject] = {
    "mug": ProceduralObject("mug", "hollow cylinder with a ring handle: genus 1, a concavity, banded texture",
                            mug_sdf, mug_texture),
}


def get_object(name: str) -> ProceduralObject:
    if name not in OBJECTS:
        raise ConfigError(f"unknown procedural object {name!r}; known: {', '.join(OBJECTS)}")
    return OBJECTS[name]


def mesh_from_sdf(sdf: SDF, resolution: int = 160, bound: float = 0.55) -> trimesh.Trimesh:
    """Marching cubes of the zero level set of ``sdf`` on a grid over [-bound, bound]^3."""
    from skimage.measure import marching_cubes

    axis = np.linspace(-bound, bound, resolution, dtype=np.float32)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    values = sdf(grid).reshape(resolution, resolution, resolution)
    spacing = (2 * bound) / (resolution - 1)
    verts, faces, _, _ = marching_cubes(values, level=0.0, spacing=(spacing,) * 3)
    mesh = trimesh.Trimesh(verts - bound, faces, process=True)
    if mesh.volume < 0:  # make normals point outwards whatever the library's winding
        mesh.invert()
    return mesh
