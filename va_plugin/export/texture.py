"""Textured meshes: a mesh's texture baked from the input views, and baking a loaded run's mesh.

Per texel: every view's color and weight (:mod:`va_plugin.export.views`), levelled across views and
fused (:mod:`va_plugin.export.fusion`); texels no view sees take the color of the nearest seen surface
(:mod:`va_plugin.export.fill`); empty texels around the atlas charts (:mod:`va_plugin.export.atlas`) are
dilated so filtering does not bleed into seams.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import torch
import trimesh

from va_plugin.errors import VAError
from va_plugin.export.atlas import MAX_TEXTURE_FACES, dilate, rasterize_uv, simplify_for_texture, unwrap
from va_plugin.export.baked import BakeReport, TexturedMesh
from va_plugin.export.config import ExportConfig, check_texture_size
from va_plugin.export.fill import fill_from_seen
from va_plugin.export.frame import check_frame
from va_plugin.export.fusion import FUSIONS, apply_harmonisation, fuse, harmonise
from va_plugin.export.inconsistency import inconsistency_maps
from va_plugin.export.views import OPAQUE, Views, view_samples
from va_plugin.export.writing import bake_picture, check_texture_output, write_bake_record, write_textured_mesh
from va_plugin.raycast import smooth_vertex_normals
from va_plugin.utils.memory import check_texture_memory, small_numpy_pages

Fallback = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""Colors ``[m, 3]`` of surface points ``[m, 3]`` with normals ``[m, 3]``."""


@small_numpy_pages()
def bake_texture(mesh: trimesh.Trimesh, views: Views, size: int = ExportConfig.texture_size,
                 fusion: str = ExportConfig.fusion,
                 fallback: Fallback | None = None, progress: bool = False, atlas=None,
                 harmonise_views: bool | None = None, max_faces: int | None = MAX_TEXTURE_FACES,
                 fill_unseen: bool = True):
    """UV-unwrap ``mesh`` (simplified to ``max_faces`` first) and bake its texture from ``views``:
    ``(TexturedMesh, BakeReport)``. ``fallback``: the color of texels no view sees (None: the nearest seen
    surface's, :func:`~va_plugin.export.fill.fill_from_seen`). ``atlas``: the
    ``(vertices, faces, uv)`` of an earlier :func:`~va_plugin.export.atlas.unwrap` at this size, reused.
    ``harmonise_views``: level the views' colors before fusing (None: with robust fusion only).
    ``fill_unseen=False``: texels no view sees get no color of their own; the padding around the charts
    spreads the seen texels' colors over them in the atlas image (the benchmark's ground-truth textures).
    Raises VAError for a mesh without faces, a bad texture size, or a view that sees none of the mesh."""
    check_texture_size(size)
    check_texture_memory(size, len(views))
    if fusion not in FUSIONS:
        raise VAError(f"unknown fusion {fusion!r}; use one of {', '.join(FUSIONS)}")
    if len(np.asarray(mesh.faces)) == 0:
        raise VAError("the mesh has no faces: nothing to texture")
    seconds = {}
    if atlas is None:
        started = time.perf_counter()
        mesh = simplify_for_texture(mesh, max_faces)
        seconds["simplify"] = time.perf_counter() - started
    started = time.perf_counter()
    vertices, faces, uv = unwrap(mesh, size)[:3] if atlas is None else atlas
    seconds["unwrap"] = time.perf_counter() - started
    started = time.perf_counter()
    face, bary = rasterize_uv(uv, faces, size)
    covered = face >= 0
    fid, b = face[covered], bary[covered]
    corners = faces[fid]
    points = np.einsum("mk,mkc->mc", b, vertices[corners]).astype(np.float32)
    vertex_normals = smooth_vertex_normals(vertices, faces)
    normals = np.einsum("mk,mkc->mc", b, vertex_normals[corners])
    normals /= np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
    colors, weights, in_view = view_samples(vertices, faces, points, normals, views, progress=progress)
    view_texels = [int(c) for c in (weights > 0).sum(0)]
    blind = [k for k in range(len(views)) if not in_view[k]]
    if blind:
        raise VAError(f"training view{'s' if len(blind) > 1 else ''} {', '.join(map(str, blind))} see"
                      f"{'' if len(blind) > 1 else 's'} no texel of the mesh (the mesh lies outside "
                      f"{'their' if len(blind) > 1 else 'its'} image or mask): the mesh and the run's cameras "
                      "do not fit together")
    gains = None
    if harmonise_views if harmonise_views is not None else fusion == "robust":
        gains = harmonise(colors, weights)
        colors = apply_harmonisation(colors, weights, gains)
    seen = (weights > 0).any(1)
    fused, share = fuse(colors, weights, fusion)
    if (~seen).any() and fill_unseen:
        if fallback is None:
            fused = fill_from_seen(points, normals, fused, seen)
        else:
            fused[~seen] = np.clip(fallback(points[~seen], normals[~seen]), 0.0, 1.0)
    seconds["bake"] = time.perf_counter() - started
    image = np.zeros((size, size, 3), np.float32)
    filled = np.zeros((size, size), bool)
    rows, cols = np.nonzero(covered)
    image[rows, cols] = fused
    known = np.ones_like(seen) if fill_unseen else seen
    filled[rows[known], cols[known]] = True
    image = dilate(image, filled)
    maps = np.zeros((len(views), size, size), np.float32)
    maps[:, rows, cols] = share.T
    report = BakeReport(maps, int(covered.sum()), int(seen.sum()), view_texels, seconds, gains)
    return TexturedMesh(vertices, faces, uv, np.clip(image, 0.0, 1.0)), report


def run_views(pipeline, inconsistency: bool = False, progress: bool = False, opaque: float = OPAQUE) -> Views:
    """The training views of a loaded run, a pixel inside the object where its mask is at least ``opaque``;
    with ``inconsistency`` (view-adaptive runs) also their inconsistency maps (|own-branch render -
    canonical render|, half resolution)."""
    dm = pipeline.datamanager
    masks = None if dm.masks is None else dm.masks.cpu().numpy().reshape(dm.images.shape[:3]) >= opaque
    maps = None
    if inconsistency:
        if not pipeline.model.field.has_view_branches or not pipeline.model.field.branches_active():
            raise VAError("--use-inconsistency needs a view-adaptive run (va-neus, va-ngp) whose branches trained")

        maps = np.stack([v["map"] for v in inconsistency_maps(pipeline, scale=0.5, progress=progress)])
    return Views(dm.cameras.to(torch.device("cpu")), dm.images.cpu().numpy().astype(np.float32), masks, maps)


def texture_run_mesh(pipeline, mesh: trimesh.Trimesh, output: Path | Sequence[Path], export: ExportConfig,
                     inconsistency: bool = False, progress: bool = True, harmonise_views: bool | None = None,
                     record: dict | None = None):
    """Bake ``mesh`` from a loaded run's training views (``export``: the texture size, face count, fusion and
    frame), write it to ``output`` (GLB or OBJ+MTL+PNG; several paths: one bake written in each format) in
    the frame with ``<stem>_frame.json``, and ``<stem>_bake.png`` (atlas | per-view weight maps) and
    ``<stem>_bake.json`` beside the first (with ``record`` added to the JSON); returns ``(TexturedMesh,
    BakeReport, written paths)``. The TexturedMesh stays in the training frame."""
    outputs = [Path(output)] if isinstance(output, (str, Path)) else [Path(o) for o in output]
    for path in outputs:
        check_texture_output(path)
    check_frame(export.frame)
    views = run_views(pipeline, inconsistency=inconsistency, progress=progress)
    textured, report = bake_texture(mesh, views, size=export.texture_size, fusion=export.fusion, progress=progress,
                                    harmonise_views=harmonise_views, max_faces=export.texture_faces)
    written: list[Path] = []
    # one thread per file: most of a write is the texture's PNG encoding, which runs outside the GIL
    with ThreadPoolExecutor(max_workers=len(outputs)) as pool:
        for files in list(pool.map(lambda path: write_textured_mesh(textured, path, export.frame), outputs)):
            written.extend(p for p in files if p not in written)
    first = outputs[0]
    written.append(bake_picture(textured, report, first.with_name(first.stem + "_bake.png")))
    written.append(write_bake_record(report, first.with_name(first.stem + "_bake.json"),
                                     {"texture_size": export.texture_size, "fusion": export.fusion,
                                      "inconsistency_maps": inconsistency, "faces_extracted": len(mesh.faces),
                                      "faces_textured": len(textured.faces), "max_faces": export.texture_faces,
                                      "frame": export.frame, **(record or {})}))
    return textured, report, written
