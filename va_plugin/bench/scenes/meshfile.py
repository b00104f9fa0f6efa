"""Textured mesh files (OBJ, PLY, GLB...) as benchmark objects.

A mesh is turned z-up (``up_axis``), turned about z by ``yaw_deg`` and normalised to fit [-0.5, 0.5]^3
(largest side 1, centred). Its albedo is the texture at the hit's UV, else the vertex colors, else grey.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from va_plugin.data.images import read_image
from va_plugin.errors import ConfigError, DataError
from va_plugin.raycast import Albedo, UVTexture

UP_AXES = ("y", "z")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
PLAIN_GREY = np.array([0.7, 0.7, 0.7], dtype=np.float32)


@dataclass
class TexturedMesh:
    """A render mesh (vertices split along UV seams, as stored), its albedo, and the welded ground truth."""

    render_mesh: trimesh.Trimesh
    albedo: Albedo
    ground_truth: trimesh.Trimesh
    texture_path: Path | None


def up_to_z(up_axis: str) -> np.ndarray:
    """``[3, 3]`` rotation taking the file's up axis to +z (y-up: +90 deg about x, (x, y, z) -> (x, -z, y))."""
    if up_axis not in UP_AXES:
        raise ConfigError(f"unknown up axis {up_axis!r}; use one of {', '.join(UP_AXES)}")
    if up_axis == "z":
        return np.eye(3)
    return np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def normalise_vertices(vertices: np.ndarray) -> np.ndarray:
    """Scale ``[v, 3]`` so the bounding box's largest side is 1, then centre the box at the origin."""
    low, high = vertices.min(0), vertices.max(0)
    scale = 1.0 / float((high - low).max())
    return (vertices - 0.5 * (low + high)) * scale


def find_texture(path: Path, mesh: trimesh.Trimesh) -> Path | None:
    """The texture image of a mesh file: the material's own file, ``<stem>.png`` or ``<stem>_texture.png``,
    or else the only image in the file's folder."""
    material = mesh.visual.material if isinstance(mesh.visual, trimesh.visual.TextureVisuals) else None
    own = material.image if isinstance(material, trimesh.visual.material.SimpleMaterial) else None
    own_name = None
    if own is not None:  # a PIL image; one read from a file knows its name
        from PIL import ImageFile

        own_name = own.filename if isinstance(own, ImageFile.ImageFile) else None
    if own_name and Path(own_name).is_file():
        return Path(own_name)
    for name in (path.stem, f"{path.stem}_texture"):
        for suffix in IMAGE_SUFFIXES:
            if (path.parent / f"{name}{suffix}").is_file():
                return path.parent / f"{name}{suffix}"
    images = sorted(p for p in path.parent.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    return images[0] if len(images) == 1 else None


def _load_mesh(path: Path) -> trimesh.Trimesh:
    if not path.is_file():
        raise DataError(f"mesh file not found: {path}")
    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)  # process=False keeps UVs per vertex
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise DataError(f"cannot read mesh file {path}: {exc}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise DataError(f"{path} holds no triangles")
    return mesh


def _albedo(mesh: trimesh.Trimesh, texture: Path | None) -> Albedo:
    uv = mesh.visual.uv if isinstance(mesh.visual, trimesh.visual.TextureVisuals) else None
    if texture is not None and uv is not None and len(uv) == len(mesh.vertices):
        return UVTexture(uv, read_image(texture)[:, :, :3])
    if isinstance(mesh.visual, trimesh.visual.ColorVisuals) and mesh.visual.kind == "vertex":
        colors = np.asarray(mesh.visual.vertex_colors[:, :3], dtype=np.float32) / 255.0
        return lambda hits: np.einsum("nk,nkc->nc", hits.barycentric, colors[hits.corners])
    return lambda hits: np.broadcast_to(PLAIN_GREY, (len(hits.points), 3)).copy()


def load_textured_mesh(path: Path, texture: Path | None = None, up_axis: str = "y",
                       yaw_deg: float = 0.0) -> TexturedMesh:
    """Read a mesh file, bring it into the benchmark frame, and attach its texture."""
    path = Path(path)
    rotation = up_to_z(up_axis)
    mesh = _load_mesh(path)
    if texture is None:
        texture = find_texture(path, mesh)
    elif not Path(texture).is_file():
        raise DataError(f"texture image not found: {texture}")
    yaw = np.radians(yaw_deg)
    turn = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    vertices = normalise_vertices(np.asarray(mesh.vertices, dtype=np.float64) @ (turn @ rotation).T)
    render_mesh = trimesh.Trimesh(vertices.astype(np.float32), mesh.faces, process=False)
    # Welding the copies split along UV seams closes the surface again (Spot is watertight once welded).
    ground_truth = trimesh.Trimesh(vertices, mesh.faces, process=True)
    return TexturedMesh(render_mesh, _albedo(mesh, None if texture is None else Path(texture)), ground_truth,
                        None if texture is None else Path(texture))
