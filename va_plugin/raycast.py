"""Rendering meshes with open3d's ray caster (CPU): RGBA images with anti-aliased edges.

Materials see the *rest* surface, so on deformed vertices the texture moves with the surface.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
import trimesh

from va_plugin.utils.interrupts import interrupt_deferred

with interrupt_deferred():  # open3d's module init turns a Ctrl-C into "ImportError: initialization failed"
    import open3d as o3d

from va_plugin.cameras import Cameras

# A fixed world-space light makes shading view-independent, so clean renders are multi-view consistent.
LIGHT_DIRECTION = np.array([0.3, 0.4, 0.85]) / np.linalg.norm([0.3, 0.4, 0.85])
AMBIENT = 0.45
CAST_BATCH = 1 << 20
"""Rays :meth:`MeshRenderer.render` casts at once at most (its supersampled copies of a view, grouped)."""


@dataclass
class SurfaceHits:
    """Where ``n`` rays hit a mesh."""

    points: np.ndarray  # [n, 3] hit positions on the rest (undeformed) mesh
    corners: np.ndarray  # [n, 3] vertex ids of the hit triangles
    barycentric: np.ndarray  # [n, 3] weights of those corners


Albedo = Callable[[SurfaceHits], np.ndarray]


def position_albedo(texture: Callable[[np.ndarray], np.ndarray]) -> Albedo:
    """An albedo from a texture of 3D position ``[n, 3] -> [n, 3]``."""
    return lambda hits: texture(hits.points)


class UVTexture:
    """An albedo sampled bilinearly from an image ``[h, w, 3]`` at per-vertex UVs ``[v, 2]`` (v up, clamped)."""

    def __init__(self, uv: np.ndarray, image: np.ndarray) -> None:
        self.uv = np.asarray(uv, dtype=np.float32)
        self.image = np.asarray(image, dtype=np.float32)

    def __call__(self, hits: SurfaceHits) -> np.ndarray:
        uv = np.einsum("nk,nkc->nc", hits.barycentric, self.uv[hits.corners])
        h, w = self.image.shape[:2]
        x = np.clip(uv[:, 0], 0.0, 1.0) * (w - 1)
        y = np.clip(1.0 - uv[:, 1], 0.0, 1.0) * (h - 1)
        x0, y0 = np.minimum(np.floor(x).astype(np.int64), w - 2), np.minimum(np.floor(y).astype(np.int64), h - 2)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        im = self.image
        top = im[y0, x0] * (1 - fx) + im[y0, x0 + 1] * fx
        bottom = im[y0 + 1, x0] * (1 - fx) + im[y0 + 1, x0 + 1] * fx
        return (top * (1 - fy) + bottom * fy).astype(np.float32)


def smooth_vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals ``[v, 3]``, welding vertices that share a position (UV seams)."""
    _, weld = np.unique(vertices, axis=0, return_inverse=True)
    weld = weld.reshape(-1)
    tri = vertices[faces]
    face_normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = 2 * area
    acc = np.zeros((weld.max() + 1, 3), np.float64)
    for k in range(3):
        np.add.at(acc, weld[faces[:, k]], face_normals)
    acc /= np.maximum(np.linalg.norm(acc, axis=-1, keepdims=True), 1e-12)
    return acc[weld].astype(np.float32)


class MeshRenderer:
    """Casts rays against a triangle mesh and shades hits with a fixed world light. ``albedo``
    (``SurfaceHits -> [n, 3]`` in [0, 1]) sees the rest ``mesh``; optional deformed ``vertices [v, 3]``
    give the geometry."""

    def __init__(self, mesh: trimesh.Trimesh, albedo: Albedo, vertices: np.ndarray | None = None) -> None:
        self.mesh = mesh
        self.albedo = albedo
        self.faces = np.asarray(mesh.faces, dtype=np.int64)
        self.rest_vertices = np.asarray(mesh.vertices, dtype=np.float32)
        self.vertices = self.rest_vertices if vertices is None else np.asarray(vertices, dtype=np.float32)
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor(self.vertices), o3d.core.Tensor(self.faces.astype(np.uint32)))
        self.vertex_normals = smooth_vertex_normals(self.vertices, self.faces)

    def deformed(self, vertices: np.ndarray) -> MeshRenderer:
        """The same mesh and material with its vertices moved to ``vertices [v, 3]``."""
        return MeshRenderer(self.mesh, self.albedo, vertices)

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Hit distance ``[n]`` (inf on a miss), face ids ``[n]`` and barycentrics ``[n, 3]`` of rays ``[n, 3]``."""
        rays = o3d.core.Tensor(np.concatenate([origins, directions], -1).astype(np.float32))
        result = self.scene.cast_rays(rays)
        uv = result["primitive_uvs"].numpy()
        bary = np.stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], -1)  # o3d: p = (1-u-v) a + u b + v c
        return result["t_hit"].numpy(), result["primitive_ids"].numpy().astype(np.int64), bary

    def shade(self, face_ids: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """Shaded colors ``[n, 3]`` of hits given by face ids ``[n]`` and barycentrics ``[n, 3]``."""
        corners = self.faces[face_ids]
        points = np.einsum("nk,nkc->nc", bary, self.rest_vertices[corners])
        normals = self.hit_normals(face_ids, bary)
        diffuse = np.clip(normals @ LIGHT_DIRECTION, 0.0, 1.0)[:, None]
        albedo = self.albedo(SurfaceHits(points.astype(np.float32), corners, bary.astype(np.float32)))
        return np.clip(albedo * (AMBIENT + (1.0 - AMBIENT) * diffuse), 0.0, 1.0)

    def hit_normals(self, face_ids: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """Unit smoothed normals ``[n, 3]`` of hits given by face ids ``[n]`` and barycentrics ``[n, 3]``."""
        normals = np.einsum("nk,nkc->nc", bary, self.vertex_normals[self.faces[face_ids]])
        normals /= np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
        return normals

    def pixel_rays(self, cameras: Cameras, index: int, dy: float = 0.0, dx: float = 0.0
                   ) -> tuple[np.ndarray, np.ndarray]:
        """World rays ``[H*W, 3]`` through every pixel of view ``index``, shifted by ``(dy, dx)`` pixels."""
        _, rows, cols = cameras.pixel_grid(index)
        origins, directions = cameras.generate_rays(index, rows.float() + dy, cols.float() + dx)
        return origins.numpy(), directions.numpy()

    def render(self, cameras: Cameras, index: int, supersample: int = 2) -> np.ndarray:
        """RGBA float32 ``[H, W, 4]`` of one view (straight alpha), averaged over ``supersample^2`` rays."""
        height, width = cameras.height, cameras.width
        pixels = height * width
        offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
        shifts = [(dy, dx) for dy in offsets for dx in offsets]
        _, rows, cols = cameras.pixel_grid(index)
        rows, cols = rows.float(), cols.float()
        rgb_sum = np.zeros((pixels, 3), np.float32)
        hits = np.zeros((pixels, 1), np.float32)
        group = max(1, CAST_BATCH // max(pixels, 1))  # shifted copies of the view cast together
        for start in range(0, len(shifts), group):
            part = shifts[start:start + group]
            dy = torch.tensor([d for d, _ in part], dtype=torch.float32)[:, None]
            dx = torch.tensor([d for _, d in part], dtype=torch.float32)[:, None]
            origins, directions = cameras.generate_rays(index, (rows + dy).reshape(-1), (cols + dx).reshape(-1))
            t, faces, bary = self.cast(origins.numpy(), directions.numpy())
            hit = np.isfinite(t)
            rgb = np.zeros((len(t), 3), np.float32)
            if hit.any():
                rgb[hit] = self.shade(faces[hit], bary[hit])
            for k in range(len(part)):  # in the order of the shifts, as one cast each would add them
                rgb_sum += rgb[k * pixels:(k + 1) * pixels]
                hits[:, 0] += hit[k * pixels:(k + 1) * pixels]
        alpha = hits / supersample**2
        rgb = np.where(hits > 0, rgb_sum / np.maximum(hits, 1.0), 0.0)
        return np.concatenate([rgb, alpha], -1).reshape(height, width, 4).astype(np.float32)

    def normals(self, cameras: Cameras, index: int) -> np.ndarray:
        """World-space unit normals and coverage ``[H, W, 4]`` (normal, then 1 where the pixel centre's ray
        hits, 0 elsewhere, with a zero normal) of one view: the smoothed vertex normals at each hit, turned to
        face the camera, as a generator's normal map shows the visible side."""
        origins, directions = self.pixel_rays(cameras, index, 0.0, 0.0)
        t, faces, bary = self.cast(origins, directions)
        hit = np.isfinite(t)
        out = np.zeros((len(t), 4), np.float32)
        if hit.any():
            normals = self.hit_normals(faces[hit], bary[hit])
            normals *= np.where((normals * directions[hit]).sum(-1, keepdims=True) > 0, -1.0, 1.0)
            out[hit, :3] = normals
            out[hit, 3] = 1.0
        return out.reshape(cameras.height, cameras.width, 4)

    def depth(self, cameras: Cameras, index: int) -> np.ndarray:
        """Depth along the optical axis ``[H, W]`` at pixel centres (inf where a ray misses)."""
        origins, directions = self.pixel_rays(cameras, index, 0.0, 0.0)
        t, _, _ = self.cast(origins, directions)
        forward = cameras.c2w[index, :, 2].numpy()
        return (t * (directions @ forward)).reshape(cameras.height, cameras.width).astype(np.float32)
