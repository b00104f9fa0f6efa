"""UV atlases of extracted meshes: simplification before the unwrap, the xatlas unwrap, the texels each
triangle covers, and the padding of the charts in the baked image.

Conventions: ``uv`` has v up (OBJ, trimesh); texel ``(row r, column c)`` of an ``S x S`` texture sits at
``uv = ((c + 0.5) / S, 1 - (r + 0.5) / S)``.
"""

from __future__ import annotations

import cv2
import numpy as np
import trimesh

from va_plugin.errors import VAError
from va_plugin.raycast import o3d

PADDING_TEXELS = 16
"""Texels by which :func:`dilate` grows the charts of a baked image."""
MAX_TEXTURE_FACES = 40_000
"""Meshes with more faces are simplified (quadric decimation) before the UV unwrap, whose time grows
steeply with the face count on noisy surfaces."""


def simplify_for_texture(mesh: trimesh.Trimesh, max_faces: int | None = MAX_TEXTURE_FACES) -> trimesh.Trimesh:
    """``mesh`` with at most ``max_faces`` faces (open3d's quadric decimation, which keeps the shape where
    it is flat), or ``mesh`` itself when it has no more, or ``max_faces`` is 0 or None."""
    faces = np.asarray(mesh.faces)
    if not max_faces or len(faces) <= max_faces:
        return mesh
    if max_faces < 4:
        raise VAError(f"--faces must be 0 (keep every face) or at least 4, got {max_faces}")
    simple = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(mesh.vertices, np.float64)),
                                       o3d.utility.Vector3iVector(faces.astype(np.int32)))
    simple = simple.simplify_quadric_decimation(target_number_of_triangles=int(max_faces))
    simple.remove_degenerate_triangles()
    simple.remove_unreferenced_vertices()
    return trimesh.Trimesh(np.asarray(simple.vertices, np.float32), np.asarray(simple.triangles, np.int64),
                           process=False)


def unwrap(mesh: trimesh.Trimesh, size: int, padding: int = 4):
    """xatlas charts packed into one ``size x size`` atlas: ``vertices [v', 3]``, ``faces [f, 3]``, ``uv [v', 2]``
    (v up) and ``source [v']``, the original vertex of each (seam vertices are duplicated)."""
    import xatlas

    faces = np.asarray(mesh.faces)
    if len(faces) == 0:
        raise VAError("the mesh has no faces: nothing to texture")
    atlas = xatlas.Atlas()
    atlas.add_mesh(np.asarray(mesh.vertices, np.float32), faces.astype(np.uint32))
    pack = xatlas.PackOptions()
    pack.resolution = size
    pack.padding = padding
    pack.bilinear = True
    atlas.generate(xatlas.ChartOptions(), pack)
    if atlas.atlas_count != 1:
        # a fixed resolution lets xatlas spill charts into more atlases: scale them into one instead
        pack.resolution = 0
        pack.texels_per_unit = 0.0
        atlas.generate(xatlas.ChartOptions(), pack)
    source, new_faces, uv = atlas[0]
    uv = np.asarray(uv, np.float32).copy()
    uv[:, 1] = 1.0 - uv[:, 1]  # xatlas' v runs down the atlas image; ours runs up
    source = np.asarray(source, np.int64)
    return np.asarray(mesh.vertices, np.float32)[source], np.asarray(new_faces, np.int64), uv, source


def rasterize_uv(uv: np.ndarray, faces: np.ndarray, size: int):
    """Which triangle covers each texel centre, and where: ``face [S, S]`` int64 (-1: none) and
    ``bary [S, S, 3]``."""
    corners = np.stack([uv[:, 0] * size, (1.0 - uv[:, 1]) * size, np.zeros(len(uv))], -1).astype(np.float32)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(corners), o3d.core.Tensor(faces.astype(np.uint32)))
    rows, cols = np.meshgrid(np.arange(size, dtype=np.float32), np.arange(size, dtype=np.float32), indexing="ij")
    origins = np.stack([cols + 0.5, rows + 0.5, np.ones_like(rows)], -1).reshape(-1, 3)
    rays = np.concatenate([origins, np.broadcast_to(np.float32([0, 0, -1]), origins.shape)], -1)
    result = scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays, np.float32)))
    hit = np.isfinite(result["t_hit"].numpy())
    face = np.where(hit, result["primitive_ids"].numpy().astype(np.int64), -1)
    b = result["primitive_uvs"].numpy()
    bary = np.stack([1.0 - b[:, 0] - b[:, 1], b[:, 0], b[:, 1]], -1)  # o3d: (1-u-v) a + u b + v c
    return face.reshape(size, size), bary.reshape(size, size, 3).astype(np.float32)


def dilate(image: np.ndarray, filled: np.ndarray, iterations: int = PADDING_TEXELS) -> np.ndarray:
    """Grow the filled texels of ``image [S, S, 3]`` outwards by ``iterations`` texels (mean of the filled
    3x3 neighbours), then give any still-empty texel the mean color."""
    image = np.where(filled[..., None], image, 0.0).astype(np.float32)
    filled = filled.astype(np.float32)
    for _ in range(iterations):
        if filled.min() > 0:
            break
        total = cv2.boxFilter(image * filled[..., None], -1, (3, 3), normalize=False)
        count = cv2.boxFilter(filled, -1, (3, 3), normalize=False)
        grow = (filled == 0) & (count > 0)
        image[grow] = total[grow] / count[grow][:, None]
        filled[grow] = 1.0
    if filled.min() == 0:
        mean = image[filled > 0].mean(0) if filled.any() else np.full(3, 0.5, np.float32)
        image[filled == 0] = mean
    return image
