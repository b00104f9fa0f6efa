"""Marching-cubes meshes with vertex colors from a trained model."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import torch
import trimesh

from va_plugin.errors import ConfigError, VAError
from va_plugin.export.config import FACES_MAX_RESOLUTION, ExportConfig
from va_plugin.export.frame import check_frame, frame_applies, frame_transform, write_frame_record
from va_plugin.fields.encodings.hash_kernel import denormals_flushed
from va_plugin.models.base import Model
from va_plugin.utils.memory import check_mesh_resolution

MESH_FORMATS = (".ply", ".obj", ".glb")
FACES_MARGIN = 1.15
"""How far past the asked face count the finer grid of :func:`mesh_for_faces` aims (a surface's faces grow
as the grid squared)."""


@torch.no_grad()
def sample_grid(fn, resolution: int, bound: float, device: torch.device, chunk: int = 65536) -> np.ndarray:
    """``fn`` on a ``resolution^3`` grid over [-bound, bound]^3, as ``[R, R, R]`` (x, y, z order)."""
    axis = torch.linspace(-bound, bound, resolution, device=device)
    return _sample_axes(fn, axis[:, None].expand(-1, 1), axis, chunk)


def _sample_axes(fn, xs: torch.Tensor, axis: torch.Tensor, chunk: int) -> np.ndarray:
    """``fn`` on the grid ``xs x axis x axis`` (``xs [n, 1]``), as ``[n, len(axis), len(axis)]``."""
    values = []
    side = len(axis)
    with denormals_flushed(axis.device.type == "cpu"):  # far from the surface the field underflows
        for part in torch.split(xs[:, 0], max(1, chunk // (side * side))):
            grid = torch.stack(torch.meshgrid(part, axis, axis, indexing="ij"), -1).reshape(-1, 3)
            values.append(fn(grid).reshape(len(part), side, side).float().cpu())
    return torch.cat(values).numpy()


BLOCK = 2
"""Cells per side of the blocks in which :func:`sample_distance_grid` skips the field."""


@torch.no_grad()
def sample_distance_grid(fn, resolution: int, bound: float, radius: float, device: torch.device,
                         lipschitz: float, chunk: int = 65536) -> np.ndarray:
    """The grid ``[resolution, resolution, resolution]`` (float32) of :func:`sample_grid` for a signed
    distance ``fn`` (points ``[m, 3]`` -> ``[m]``) whose gradient norm stays below
    ``lipschitz``, evaluating ``fn`` only where a surface may pass: first at the corners of blocks of
    ``BLOCK^3`` cells, then at every point of the blocks whose corner values, widened by ``lipschitz``
    times the distance to the nearest corner, do not rule out a sign change, and that lie not wholly
    outside the sphere of ``radius`` (which :func:`extract_mesh` counts as empty). Elsewhere the grid
    holds a value of the right sign (the bound nearest zero), so marching cubes, which reads the values
    only in cells where the sign changes, sees the same grid."""
    n = resolution
    spacing = 2.0 * bound / (n - 1)
    corners = np.unique(np.r_[np.arange(0, n, BLOCK), n - 1])  # fine indices of the block corners
    axis = torch.linspace(-bound, bound, n, device=device)
    coarse = _sample_axes(fn, axis[corners][:, None], axis[corners], chunk)  # [k, k, k]
    k = len(corners)
    # per block: the corner values' range, widened by lipschitz x (half the block diagonal)
    shifted = [coarse[i:k - 1 + i, j:k - 1 + j, l:k - 1 + l] for i in (0, 1) for j in (0, 1) for l in (0, 1)]
    low, high = np.minimum.reduce(shifted), np.maximum.reduce(shifted)
    half = 0.5 * np.diff(corners) * spacing  # [k - 1] half the block's side, per axis
    reach = lipschitz * np.sqrt(half[:, None, None] ** 2 + half[None, :, None] ** 2 + half[None, None, :] ** 2)
    low, high = low - reach, high + reach
    # the blocks' nearest and farthest distances from the centre against the sphere
    lo = np.linspace(-bound, bound, n)[corners[:-1]]
    hi = np.linspace(-bound, bound, n)[corners[1:]]
    near_axis = np.where(lo > 0, lo, np.where(hi < 0, -hi, 0.0))
    far_axis = np.maximum(np.abs(lo), np.abs(hi))
    nearest = np.sqrt(near_axis[:, None, None] ** 2 + near_axis[None, :, None] ** 2 + near_axis[None, None, :] ** 2)
    farthest = np.sqrt(far_axis[:, None, None] ** 2 + far_axis[None, :, None] ** 2 + far_axis[None, None, :] ** 2)
    inside = (high < 0) & (farthest < radius)  # every point inside the object and the sphere
    empty = (low > 0) | (nearest > radius)  # every point outside one of them
    crossing = ~inside & ~empty
    # each grid index lies in one block, or two where it is a block corner: a point is evaluated when
    # any block it belongs to may hold a crossing
    index = np.arange(n)
    first = np.clip(np.searchsorted(corners, index, side="right") - 1, 0, k - 2)
    second = np.where(np.isin(index, corners) & (index > 0), np.clip(first - 1, 0, k - 2), first)
    second = np.where(index == n - 1, k - 2, second)
    first = np.where(index == n - 1, k - 2, first)
    wanted = np.zeros((n, n, n), bool)
    for bx in (first, second):
        for by in (first, second):
            for bz in (first, second):
                wanted |= crossing[np.ix_(bx, by, bz)]
    values = np.where(inside, high, np.where(low > 0, low, np.float32(spacing)))[np.ix_(first, first, first)]
    values = values.astype(np.float32)
    points = torch.from_numpy(np.argwhere(wanted)).to(device)
    if len(points):
        with denormals_flushed(axis.device.type == "cpu"):
            found = torch.cat([fn(axis[part]).float().cpu() for part in torch.split(points, chunk)])
        values[wanted] = found.numpy()
    return values


def extract_mesh(model: Model, resolution: int = ExportConfig.mesh_resolution, bound: float | None = None,
                 with_color: bool = True, largest_component: bool = False) -> trimesh.Trimesh:
    """The model's surface as a mesh: marching cubes of ``model.mesh_field`` inside the scene bound (a
    signed distance, ``model.mesh_field_lipschitz`` set, is evaluated only near its zero crossings), after
    the model's ``prepare_mesh_grid(values, spacing)`` and ``fill_mesh_cavities`` (``Model``'s defaults:
    unchanged, not filled).
    Raises VAError when the field has no surface inside the bound."""
    from skimage.measure import marching_cubes

    device = next(model.parameters()).device
    radius = float(model.scene.scene_radius)
    bound = radius if bound is None else bound

    was_training = model.training
    model.eval()
    try:
        lipschitz = model.mesh_field_lipschitz
        values = sample_grid(model.mesh_field, resolution, bound, device) if lipschitz is None else \
            sample_distance_grid(model.mesh_field, resolution, bound, radius, device, lipschitz)
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


def mesh_for_faces(model: Model, mesh: trimesh.Trimesh, faces: int | None, resolution: int,
                   largest_component: bool) -> tuple[trimesh.Trimesh, int]:
    """The mesh to decimate to ``faces`` and its grid: ``mesh`` itself when it has at least that many faces;
    otherwise the field extracted again on a grid fine enough to have them (faces grow as the grid
    squared; at most :data:`~va_plugin.export.config.FACES_MAX_RESOLUTION`, and only where it fits in
    memory). A mesh still short of ``faces`` is kept with a one-line warning."""
    source, grid = mesh, resolution
    if faces and len(mesh.faces) < faces:
        finer = min(FACES_MAX_RESOLUTION, math.ceil(resolution * math.sqrt(faces / max(len(mesh.faces), 1))
                                                    * FACES_MARGIN))
        try:
            check_mesh_resolution(finer)
        except ConfigError:
            finer = resolution
        if finer > resolution:
            fine = extract_mesh(model, resolution=finer, largest_component=largest_component, with_color=False)
            if len(fine.faces) > len(mesh.faces):
                source, grid = fine, finer
    if faces and len(source.faces) < faces:
        warnings.warn(f"--faces {faces}: the mesh has only {len(source.faces)} faces (on a {grid}^3 grid), so it "
                      "is textured with those (simplification removes faces, it adds none)", stacklevel=3)
    return source, grid
