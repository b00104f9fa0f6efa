"""Rendering meshes with open3d's ray caster (CPU): RGBA images with anti-aliased edges."""

from __future__ import annotations

from typing import Callable

import numpy as np
import open3d as o3d
import torch
import trimesh

from va_plugin.cameras import Cameras

# A fixed world-space light makes shading view-independent, so clean renders are multi-view consistent.
LIGHT_DIRECTION = np.array([0.3, 0.4, 0.85]) / np.linalg.norm([0.3, 0.4, 0.85])
AMBIENT = 0.45


class MeshRenderer:
    """Casts rays against a triangle mesh; colours hits with ``albedo(points [n, 3]) -> [n, 3]``."""

    def __init__(self, mesh: trimesh.Trimesh, albedo: Callable[[np.ndarray], np.ndarray]) -> None:
        self.mesh = mesh
        self.albedo = albedo
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
                                 o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)))
        self.face_normals = np.asarray(mesh.face_normals, dtype=np.float32)

    def cast(self, origins: np.ndarray, directions: np.ndarray):
        """Hit distance ``[n]`` (inf on a miss) and face ids ``[n]`` of rays ``[n, 3]``."""
        rays = o3d.core.Tensor(np.concatenate([origins, directions], -1).astype(np.float32))
        result = self.scene.cast_rays(rays)
        return result["t_hit"].numpy(), result["primitive_ids"].numpy()

    def shade(self, points: np.ndarray, face_ids: np.ndarray) -> np.ndarray:
        normals = self.face_normals[face_ids]
        diffuse = np.clip(normals @ LIGHT_DIRECTION, 0.0, 1.0)[:, None]
        return np.clip(self.albedo(points) * (AMBIENT + (1.0 - AMBIENT) * diffuse), 0.0, 1.0)

    def render(self, cameras: Cameras, index: int, supersample: int = 2) -> np.ndarray:
        """RGBA float ``[H, W, 4]`` of one view (straight alpha), averaged over ``supersample^2`` rays."""
        height, width = cameras.height, cameras.width
        s = supersample
        offsets = (np.arange(s) + 0.5) / s - 0.5
        rows, cols = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
        rgb_sum = np.zeros((height * width, 3), np.float32)
        alpha_sum = np.zeros((height * width, 1), np.float32)
        for dy in offsets:
            for dx in offsets:
                r = torch.from_numpy((rows.reshape(-1) + dy).astype(np.float32))
                c = torch.from_numpy((cols.reshape(-1) + dx).astype(np.float32))
                idx = torch.full_like(r, index, dtype=torch.long)
                origins, directions = cameras.generate_rays(idx, r, c)
                o, d = origins.numpy(), directions.numpy()
                t, faces = self.cast(o, d)
                hit = np.isfinite(t)
                if hit.any():
                    points = o[hit] + d[hit] * t[hit, None]
                    rgb_sum[hit] += self.shade(points, faces[hit])
                    alpha_sum[hit] += 1.0
        alpha = alpha_sum / (s * s)
        rgb = np.where(alpha > 0, rgb_sum / np.maximum(alpha_sum, 1e-6), 0.0)
        return np.concatenate([rgb, alpha], -1).reshape(height, width, 4).astype(np.float32)
