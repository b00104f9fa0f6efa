"""Marching-cubes meshes with vertex colors from a trained model."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import torch
import trimesh

from va_plugin.errors import VAError
from va_plugin.export.frame import check_frame, frame_applies, frame_transform, write_frame_record
from va_plugin.fields.encodings.hash_kernel import denormals_flushed

MESH_FORMATS = (".ply", ".obj", ".glb")


@torch.no_grad()
def sample_grid(fn, resolution: int, bound: float, device: torch.device, chunk: int = 65536) -> np.ndarray:
    """``fn`` on a ``resolution^3`` grid over [-bound, bound]^3, as ``[R, R, R]`` (x, y, z order)."""
    axis = torch.linspace(-bound, bound, resolution, device=device)
    values = []
    with denormals_flushed(axis.device.type == "cpu"):  # far from the surface the field underflows
        for xs in torch.split(axis, max(1, chunk // (resolution * resolution))):
            grid = torch.stack(torch.meshgrid(xs, axis, axis, indexing="ij"), -1).reshape(-1, 3)
            values.append(fn(grid).reshape(len(xs), resolution, resolution).float().cpu())
    return torch.cat(values).numpy()


def extract_mesh(model, resolution: int = 128, bound: float | None = None, with_color: bool = True,
                 largest_component: bool = False) -> trimesh.Trimesh:
    """The model's surface as a mesh: marching cubes of ``model.mesh_field`` inside the scene bound,
    after the model's ``prepare_mesh_grid(values, spacing)`` and ``fill_mesh_cavities`` (``Model``'s defaults:
    unchanged, not filled).
    Raises VAError when the field has no surface inside the bound."""
    from skimage.measure import marching_cubes

    device = next(model.parameters()).device
    radius = float(model.scene.scene_radius)
    bound = radius if bound is None else bound

    was_training = model.training
    model.eval()
    try:
        values = sample_grid(model.mesh_field, resolution, bound, device)
    finally:
        model.train(was_training)
    if not np.isfinite(values).all():
        raise VAError("the field holds NaN or infinite values; the run diverged, so there is no mesh to extract")
    spacing = 2.0 * bound / (resolution - 1)
    values = model.prepare_mesh_grid(values, spacing)  # e.g. ngp: its density smoothed in log space
    # outside the bounding sphere counts as empty, so no surface appears beyond the bound
    values = np.maximum(values, sphere_distance_grid(resolution, bound, radius))
    if values.min() >= 0.0 or values.max() <= 0.0:
        raise VAError("the field has no surface inside the scene bound (no zero crossing); "
                      "the run may have diverged or trained too briefly")
    if model.fill_mesh_cavities:
        values = fill_enclosed_cavities(values)
    filled = inside_share_at_bound(values, bound, radius, spacing)
    if filled > BOUND_FILLED_SHARE:
        warnings.warn(f"the field is inside the object over {filled:.0%} of the bounding sphere, so most of the "
                      "mesh is the sphere itself, not an object: the run diverged (or the scene radius is too small)",
                      stacklevel=2)
    verts, faces, _, _ = marching_cubes(values, level=0.0, spacing=(spacing,) * 3)
    mesh = trimesh.Trimesh(verts - bound, faces, process=True)
    if mesh.volume < 0:
        mesh.invert()
    if largest_component:
        parts = mesh.split(only_watertight=False)
        if len(parts) > 1:
            mesh = max(parts, key=lambda m: len(m.faces))
    if with_color and len(mesh.vertices):
        points = torch.as_tensor(np.array(mesh.vertices), dtype=torch.float32, device=device)
        normals = torch.as_tensor(np.array(mesh.vertex_normals), dtype=torch.float32, device=device)
        colors = []
        model.eval()
        try:
            for p, n in zip(torch.split(points, 16384), torch.split(normals, 16384)):
                colors.append(model.surface_color(p, n).clamp(0, 1).cpu())
        finally:
            model.train(was_training)
        rgb = (torch.cat(colors).numpy() * 255 + 0.5).astype(np.uint8)
        mesh.visual.vertex_colors = np.concatenate([rgb, np.full((len(rgb), 1), 255, np.uint8)], 1)
    return mesh


def sphere_distance_grid(resolution: int, bound: float, radius: float) -> np.ndarray:
    """``|x| - radius`` on the grid of :func:`sample_grid`, ``[R, R, R]`` float32."""
    axis = np.linspace(-bound, bound, resolution, dtype=np.float32)
    return np.sqrt(axis[:, None, None] ** 2 + axis[None, :, None] ** 2 + axis[None, None, :] ** 2) - radius


def fill_enclosed_cavities(values: np.ndarray) -> np.ndarray:
    """A copy of ``values [R, R, R]`` (negative inside) with every enclosed cavity (a 6-connected
    component of empty cells that does not reach the border, which no camera sees) made inside."""
    from scipy import ndimage

    empty = values >= 0.0
    labels, count = ndimage.label(empty)
    if count <= 1:
        return values
    border = np.unique(np.concatenate([labels[[0, -1]].ravel(), labels[:, [0, -1]].ravel(),
                                       labels[:, :, [0, -1]].ravel()]))
    cavity = empty & ~np.isin(labels, border)
    out = values.copy()
    out[cavity] = -np.abs(out[cavity]) - 1e-6
    return out


BOUND_FILLED_SHARE = 0.5
"""More than this share of the bounding sphere inside the object means the mesh is mostly that sphere."""


def inside_share_at_bound(values: np.ndarray, bound: float, radius: float, spacing: float) -> float:
    """Share of the grid points in the shell just inside the bounding sphere (two cells thick) where the
    field is inside the object; ``values`` is the ``[R, R, R]`` grid of :func:`sample_grid`."""
    depth = sphere_distance_grid(values.shape[0], bound, radius)  # |x| - radius
    shell = (depth < 0.0) & (depth > -2.0 * spacing)
    return float((values[shell] < 0).mean()) if shell.any() else 0.0


def write_mesh(mesh: trimesh.Trimesh, path: Path, frame: str = "upright") -> Path:
    """Write PLY, OBJ or GLB by extension (atomically: a temporary file, then a rename). GLB and OBJ are
    written in ``frame`` (:mod:`va_plugin.export.frame`: ``upright`` turns them +Y up, standing on y = 0)
    with ``<stem>_frame.json`` beside them; PLY stays in the training frame."""
    path = Path(path)
    if path.suffix.lower() not in MESH_FORMATS:
        raise VAError(f"unknown mesh format {path.suffix!r}; use one of {', '.join(MESH_FORMATS)}")
    check_frame(frame)
    path.parent.mkdir(parents=True, exist_ok=True)
    transform = None
    if frame_applies(path):
        transform = frame_transform(np.asarray(mesh.vertices), frame)
        mesh = mesh.copy().apply_transform(transform)  # a proper rotation: the faces keep their winding
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    mesh.export(tmp)
    tmp.replace(path)
    if transform is not None:
        write_frame_record(path, frame, transform)
    return path


def export_run_mesh(pipeline, path: Path, resolution: int = 128, largest_component: bool = False,
                    frame: str = "upright") -> Path:
    """Extract and write the mesh of a trained pipeline."""
    mesh = extract_mesh(pipeline.model, resolution=resolution, largest_component=largest_component)
    return write_mesh(mesh, path, frame)
