"""The files of a run's export: the mesh with vertex colors, the textured mesh (:class:`MeshFiles`), and the
summary of a one-call reconstruction."""

from __future__ import annotations

import os
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import trimesh

from va_plugin.engine.loading import LoadedRun
from va_plugin.engine.run_folder import check_output_file
from va_plugin.errors import ConfigError
from va_plugin.export.config import ExportConfig
from va_plugin.export.frame import frame_applies, frame_record, frame_transform
from va_plugin.export.mesh import MESH_FORMATS, extract_mesh, mesh_for_faces, write_mesh
from va_plugin.export.texture import texture_run_mesh
from va_plugin.export.writing import check_texture_output
from va_plugin.utils.files import write_json
from va_plugin.utils.paths import within

MESH_FILE = "mesh.ply"
TEXTURED_MESH_FILE = "mesh.glb"
TEXTURED_OBJ_FILE = "mesh.obj"
"""Written beside ``mesh.glb`` by default, with ``mesh.mtl`` and ``mesh.png``: the same textured mesh as OBJ."""
SUMMARY_FILE = "summary.json"


@dataclass
class MeshFiles:
    """What :func:`~va_plugin.api.export_mesh` wrote, and the meshes themselves."""

    mesh: trimesh.Trimesh
    """The marching-cubes mesh (vertex colors unless textured)."""
    path: Path | None = None
    """The mesh file with vertex colors (None when only the textured mesh was asked for)."""
    textured: Any = None
    """The textured mesh (:class:`~va_plugin.export.texture.TexturedMesh`), None without a texture."""
    textured_paths: list[Path] = field(default_factory=list)
    """The textured mesh's files: the mesh files (GLB, OBJ with its MTL and PNG, ``<stem>_frame.json``), then
    its texture atlas picture and bake record."""
    report: Any = None
    """The bake's statistics (:class:`~va_plugin.export.texture.BakeReport`), None without a texture."""
    textured_source: tuple[int, int] = (0, 0)
    """The grid and the face count of the mesh the textured mesh was decimated from (a finer grid than
    ``resolution`` when ``faces`` asked for more faces than the mesh had)."""
    frame: dict[str, Any] = field(default_factory=dict)
    """The frame of the GLB / OBJ files written (:func:`~va_plugin.export.frame.frame_record`: its name, up
    axis and the 4 x 4 transforms to and from the training frame); empty when only PLY was written. The
    meshes above stay in the training frame."""

    @property
    def textured_mesh(self) -> Path | None:
        return self.textured_paths[0] if self.textured_paths else None

    @property
    def textured_obj(self) -> Path | None:
        """The textured mesh's OBJ file, when one was written."""
        return next((p for p in self.textured_paths if p.suffix.lower() == ".obj"), None)


def mesh_outputs(run_path: Path, export: ExportConfig, output: str | os.PathLike | Iterable | None,
                 vertex_colors: str | os.PathLike | None, overwrite: bool) -> tuple[list[Path], Path | None]:
    """The textured mesh's files (``output``, default ``RUN/mesh.glb`` and ``RUN/mesh.obj``; relative names
    inside the run) and the vertex-colored mesh's file, refused before any work when they cannot be
    written: an unknown format, a texture format that cannot hold one, an existing file outside a run
    folder without ``overwrite``."""
    if output is None:
        outs = [run_path / TEXTURED_MESH_FILE, run_path / TEXTURED_OBJ_FILE] if export.texture else []
    else:
        outs = [within(o, run_path, "output") for o in ([output] if isinstance(output, (str, os.PathLike))
                                                        else output)]
    plain = None if vertex_colors is None else run_path / within(vertex_colors, run_path, "vertex_colors")
    for path in outs:
        if path.suffix.lower() not in MESH_FORMATS:
            raise ConfigError(f"unknown mesh format {path.suffix!r}; use one of {', '.join(MESH_FORMATS)}")
        if export.texture:
            check_texture_output(path)
    if export.texture and not outs:
        raise ConfigError("output names no file for the textured mesh")
    for path in [*outs, *([] if plain is None else [plain])]:
        check_output_file(path, run_path, overwrite)
    return outs, plain


def write_meshes(loaded: LoadedRun, export: ExportConfig, outs: list[Path], plain: Path | None,
                 largest_component: bool = False, use_inconsistency: bool = False, harmonise: bool | None = None,
                 progress: bool = False) -> MeshFiles:
    """Extract the run's mesh and write it: with vertex colors to ``plain`` (unless None), and textured to
    ``outs`` when ``export.texture`` (see :func:`~va_plugin.api.export_mesh`)."""
    model = loaded.pipeline.model
    mesh = extract_mesh(model, resolution=export.mesh_resolution, largest_component=largest_component,
                        with_color=plain is not None or not export.texture)
    files = MeshFiles(mesh)
    if plain is not None:
        files.path = write_mesh(mesh, plain, export.frame)
        if frame_applies(files.path):
            files.frame = frame_record(export.frame, frame_transform(mesh.vertices, export.frame))
    if export.texture:
        source, grid = mesh_for_faces(model, mesh, export.faces, export.mesh_resolution, largest_component)
        files.textured, files.report, files.textured_paths = texture_run_mesh(
            loaded.pipeline, source, outs, export, use_inconsistency, progress=progress, harmonise_views=harmonise,
            record={"mesh_resolution": grid})
        files.textured_source = (grid, len(source.faces))
        files.frame = frame_record(export.frame, frame_transform(files.textured.vertices, export.frame))
    return files


def write_summary(loaded: LoadedRun, files: MeshFiles, turntable: Path | None, scores: dict[str, float],
                  resumed_from: int | None, started: float, **head: Any) -> tuple[Path, dict[str, Any]]:
    """``RUN/summary.json`` of :func:`~va_plugin.api.reconstruct`: its path and its record."""
    train_views = loaded.pipeline.datamanager.train
    record: dict[str, Any] = {
        **head, "seconds": round(time.perf_counter() - started, 1), "steps": int(loaded.state["step"]),
        "train_seconds": round(float(loaded.state["train_seconds"]), 2), "views": len(train_views),
        "masks": train_views.metadata.get("mask_source", "scene's alpha"), "mesh": str(files.path)}
    if files.textured_mesh is not None:
        record["textured_mesh"] = str(files.textured_mesh)
        record["textured_obj"] = str(files.textured_obj)
        record["textured_faces"] = len(files.textured.faces)
        record["mesh_frame"] = files.frame
    if turntable is not None:
        record["turntable"] = str(turntable)
    record["resumed_from_step"] = resumed_from
    record.update(scores)
    return write_json(loaded.path / SUMMARY_FILE, record), record
