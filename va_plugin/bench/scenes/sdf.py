"""Signed distance primitives on point arrays, boolean operators, and marching cubes.

Every primitive takes points ``p [n, 3]`` and returns distances ``[n]`` (negative inside). Booleans of
SDFs are not exact distances away from the surface, which is fine: only the zero level set is meshed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import trimesh
from scipy.spatial import cKDTree

SDF = Callable[[np.ndarray], np.ndarray]


def length(v: np.ndarray) -> np.ndarray:
    """Euclidean norm over the last axis."""
    return np.sqrt((v * v).sum(-1))


def rotation_z(degrees: float) -> np.ndarray:
    """``[3, 3]`` rotation about +z."""
    a = np.radians(degrees)
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])


def to_local(p: np.ndarray, centre: Sequence[float], yaw_deg: float = 0.0) -> np.ndarray:
    """Points in the frame of a part placed at ``centre`` and turned by ``yaw_deg`` about z."""
    return (p - np.asarray(centre, dtype=p.dtype)) @ rotation_z(yaw_deg).astype(p.dtype)


def sd_sphere(p: np.ndarray, radius: float) -> np.ndarray:
    return length(p) - radius


def sd_box(p: np.ndarray, half: Sequence[float], rounding: float = 0.0) -> np.ndarray:
    """Axis-aligned box of half extents ``half``; ``rounding`` rounds its edges inside that extent."""
    q = np.abs(p) - (np.asarray(half, dtype=p.dtype) - rounding)
    return length(np.maximum(q, 0.0)) + np.minimum(q.max(-1), 0.0) - rounding


def sd_capped_cylinder(p: np.ndarray, radius: float, half_height: float) -> np.ndarray:
    """Cylinder along z centred at the origin."""
    d = np.stack([length(p[:, :2]) - radius, np.abs(p[:, 2]) - half_height], -1)
    return np.minimum(d.max(-1), 0.0) + length(np.maximum(d, 0.0))


def sd_torus(p: np.ndarray, major: float, minor: float) -> np.ndarray:
    """Torus around the z axis."""
    q = np.stack([length(p[:, :2]) - major, p[:, 2]], -1)
    return length(q) - minor


def sd_capsule(p: np.ndarray, a: Sequence[float], b: Sequence[float], radius: float) -> np.ndarray:
    """Segment ``a``-``b`` thickened by ``radius``."""
    a, b = np.asarray(a, dtype=p.dtype), np.asarray(b, dtype=p.dtype)
    ab = b - a
    t = np.clip(((p - a) @ ab) / float(ab @ ab), 0.0, 1.0)
    return length(p - a - t[:, None] * ab) - radius


def sd_cone_frustum(p: np.ndarray, r_bottom: float, r_top: float, half_height: float) -> np.ndarray:
    """Solid truncated cone along z (radius ``r_bottom`` at -h, ``r_top`` at +h), approximately a distance:
    the side plane distance is measured along the slanted normal, then intersected with the caps."""
    slope = (r_top - r_bottom) / (2.0 * half_height)
    radius_at_z = r_bottom + (p[:, 2] + half_height) * slope
    side = (length(p[:, :2]) - radius_at_z) / np.sqrt(1.0 + slope * slope)
    return np.maximum(side, np.abs(p[:, 2]) - half_height)


def sd_polyline_tube(curve: np.ndarray, radius: float, reach: float = 0.1) -> SDF:
    """Tube of ``radius`` around a densely sampled closed curve ``[m, 3]``: distance to the nearest curve
    sample (exact to ``spacing^2 / (8 radius)``), clamped at ``reach`` to keep the query fast."""
    tree = cKDTree(curve)

    def sdf(p: np.ndarray) -> np.ndarray:
        dist, _ = tree.query(p, k=1, distance_upper_bound=reach)
        return (np.minimum(dist, reach) - radius).astype(p.dtype)

    return sdf


def union(*values: np.ndarray) -> np.ndarray:
    return np.minimum.reduce(values)


def subtract(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a`` with ``b`` carved out."""
    return np.maximum(a, -b)


def intersect(*values: np.ndarray) -> np.ndarray:
    return np.maximum.reduce(values)


def _grid_points(axis: np.ndarray, ids: Sequence[np.ndarray]) -> np.ndarray:
    """Grid positions ``[n, 3]`` of integer grid indices ``(i, j, k)``."""
    return np.stack([axis[ids[0]], axis[ids[1]], axis[ids[2]]], -1)


def sample_sdf_grid(sdf: SDF, axis: np.ndarray, coarse_step: int = 4) -> np.ndarray:
    """``sdf`` on the grid ``axis^3`` ``[r, r, r]``, evaluated exactly only in a band around the surface:
    a point whose nearest sample of a ``coarse_step`` times coarser grid is farther from the surface than
    from it (SDFs are 1-Lipschitz) keeps that sample's clamped value."""
    r = len(axis)
    spacing = float(axis[1] - axis[0])
    coarse_ids = np.arange(0, r, coarse_step)
    ci = np.meshgrid(coarse_ids, coarse_ids, coarse_ids, indexing="ij")
    coarse = sdf(_grid_points(axis, [c.reshape(-1) for c in ci])).reshape((len(coarse_ids),) * 3)
    margin = 1.5 * np.sqrt(3.0) * coarse_step * spacing
    nearest = np.minimum(np.round(np.arange(r) / coarse_step).astype(np.int64), len(coarse_ids) - 1)
    values = coarse[np.ix_(nearest, nearest, nearest)]
    band = np.nonzero(np.abs(values) < margin)
    values = np.clip(values, -margin, margin)
    values[band] = sdf(_grid_points(axis, band))
    return values.astype(np.float32)


def mesh_from_sdf(sdf: SDF, resolution: int = 160, bound: float = 0.55) -> trimesh.Trimesh:
    """Marching cubes of the zero level set of ``sdf`` on a ``resolution^3`` grid over [-bound, bound]^3:
    watertight with outward normals when the object stays inside the grid."""
    from skimage.measure import marching_cubes

    axis = np.linspace(-bound, bound, resolution, dtype=np.float32)
    values = sample_sdf_grid(sdf, axis)
    spacing = (2 * bound) / (resolution - 1)
    # (Near-)zero samples make marching cubes emit coincident vertices (non-manifold edges): nudge them out.
    eps = 1e-3 * spacing
    values[np.abs(values) < eps] = eps
    verts, faces, _, _ = marching_cubes(values, level=0.0, spacing=(spacing,) * 3)
    mesh = trimesh.Trimesh(verts - bound, faces, process=True)
    mesh.remove_unreferenced_vertices()
    if mesh.volume < 0:  # make normals point outwards whatever the library's winding
        mesh.invert()
    return mesh
