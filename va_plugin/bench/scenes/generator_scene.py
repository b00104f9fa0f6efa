"""Benchmark scenes in a generator's own layout: a GSO object or a procedural one rendered on a generator's
rig (:mod:`va_plugin.data.rigfile`) and written as that generator writes it (file names, sizes, background,
tile order: :mod:`va_plugin.bench.scenes.layouts`), with the ground-truth mesh beside it.

A scene folder holds the input (``<name>`` as the generator names it: ``sample_views.jpg``,
``pixel_images.png``, ``000000.mp4``, a ``views/`` folder...), ``mesh.ply`` (the object in the rig's world
frame) and ``scene.json`` (source, rig, level, the object's scale, the input's path). Objects keep their
unit box unless the rig's view is narrower: then they are scaled so the view holds them (``object_scale``).
The view nearest the input (azimuth 0, elevation 0) stays clean, and so do top and bottom views (a pose error
there has no defined orbit). GSO objects are rendered off their SyncDreamer renders through a texture baked
from them (:meth:`~va_plugin.bench.scenes.sources.ImageSource.baked_renderer`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from va_plugin.bench.scenes.inconsistency import KINDS, InconsistencySpec, draw_perturbation
from va_plugin.bench.scenes.layouts import write_layout
from va_plugin.bench.scenes.rig import benchmark_cameras
from va_plugin.bench.scenes.sources import ImageSource, RenderedSource, SceneSource, load_source
from va_plugin.cameras import PERSPECTIVE, Cameras
from va_plugin.data.rigfile import RigSpec, resolve_rig, rig_cameras
from va_plugin.data.visual_hull import normalise_cameras
from va_plugin.errors import ConfigError
from va_plugin.eval.evaluate import FSCORE_THRESHOLD, load_mesh
from va_plugin.eval.geometry import geometry_metrics
from va_plugin.utils.threads import single_thread

HELD_SIZE = 1.2
"""World units a view must span (at the origin) to hold a unit-box object with a margin."""
DEFAULT_TILE = 256


def input_name(spec: RigSpec) -> str:
    """The file (or folder) name the generator gives its output."""
    if spec.layout == "video":
        return "000000.mp4"
    if spec.layout == "folder":
        return "views"
    if spec.names:
        return spec.names[0].replace("*", "sample_")
    return f"{spec.name}.png"


def view_span(spec: RigSpec) -> float:
    """World units a view spans at the origin."""
    if spec.camera_type == PERSPECTIVE:
        return 2.0 * spec.distance * math.tan(math.radians(spec.fov_deg) / 2.0)
    return spec.ortho_scale


def object_scale(spec: RigSpec) -> float:
    """How much a unit-box object is shrunk so the rig's views hold it (1: not at all)."""
    return min(1.0, view_span(spec) / HELD_SIZE)


def clean_view_ids(spec: RigSpec) -> tuple[int, ...]:
    """The view nearest the generator's input, and the top and bottom views."""
    def gap(k: int) -> float:
        azimuth = min(spec.azimuths[k] % 360.0, 360.0 - spec.azimuths[k] % 360.0)
        return azimuth + abs(spec.elevations[k])

    poles = tuple(k for k, e in enumerate(spec.elevations) if abs(e) > 89.0)
    return (min(range(spec.count), key=gap), *poles)


def rendered_source(src: SceneSource, resolution: int) -> RenderedSource:
    """A source that renders from any camera: procedural ones as they are, GSO ones through their baked texture."""
    if isinstance(src, RenderedSource):
        return src
    assert isinstance(src, ImageSource)
    return RenderedSource(src.spec, src.description, src.baked_renderer(benchmark_cameras(resolution, extra=False)),
                          src.ground_truth, src.info())


def generator_cameras(spec: RigSpec, tile: int, scale: float) -> Cameras:
    """The rig's cameras around an object shrunk by ``scale`` (equivalently: the rig grown by ``1 / scale``)."""
    cameras = rig_cameras(spec, tile)
    return cameras if scale == 1.0 else normalise_cameras(cameras, torch.zeros(3), 1.0 / scale)


def build_generator_scene(out_dir: Path, rig: str | RigSpec, source: str = "procedural:mug", level: int = 0,
                          kinds: Sequence[str] | str = KINDS, seed: int = 42, tile: int | None = None,
                          data_root: Path | None = None, mesh_resolution: int = 160,
                          source_resolution: int = 256) -> Path:
    """Write ``source`` on ``rig`` (a built-in rig's name or a rig file) in the generator's layout into
    ``out_dir``; returns the input's path (what ``va-recon`` takes, with ``--data-format`` the rig's name).
    ``tile``: view size (default the generator's own); ``level``, ``kinds``, ``seed``: the inconsistency."""
    spec = resolve_rig(rig)
    tile = tile or (spec.tile_sizes[0] if spec.tile_sizes else DEFAULT_TILE)
    if not isinstance(tile, int) or tile < 8:
        raise ConfigError(f"tile must be an integer of at least 8 pixels, got {tile!r}")
    inconsistency = InconsistencySpec(kinds, level, seed, clean_view_ids(spec))
    scale = object_scale(spec)
    out_dir = Path(out_dir)
    with single_thread():
        src = rendered_source(load_source(source, source_resolution, data_root, mesh_resolution,
                                          gso_off_rig=True), source_resolution)
        cameras = generator_cameras(spec, tile, scale)
        views, normals = [], []
        for k in range(spec.count):
            p = draw_perturbation(inconsistency, k) if inconsistency.perturbs(k) else None
            views.append(src.clean(cameras, k) if p is None else src.perturbed(cameras, k, p))
            if spec.normals:
                normals.append(encode_normals(src.normals(cameras, k, p), cameras, k, spec.normal_frame))
        path = write_layout(out_dir / input_name(spec), spec, np.stack(views).astype(np.float32),
                            np.stack(normals) if normals else None)
        mesh = src.ground_truth.copy()
        mesh.apply_scale(scale)
        mesh.export(out_dir / "mesh.ply")
    info = {"source": src.spec, "rig": spec.name, "rig_file": spec.origin, "level": inconsistency.level,
            "kinds": list(inconsistency.kinds), "seed": seed, "tile": tile, "object_scale": scale,
            "clean_views": list(inconsistency.clean_views), "input": path.name, "mesh": "mesh.ply",
            "normal_maps": bool(normals)}
    (out_dir / "scene.json").write_text(json.dumps(info, indent=2))
    return path


def encode_normals(camera_normals: np.ndarray, cameras: Cameras, view: int, normal_frame: str) -> np.ndarray:
    """A normal map as the generator writes it: ``camera_normals [H, W, 4]`` (OpenCV axes of the camera that
    saw them, then coverage) taken to the world through view ``view``'s nominal pose (a view drawn from a
    wrong pose carries its error, as a generated one would), then stored ``(n + 1) / 2`` in the OpenGL axes
    of the first camera (``normal_frame`` "front") or of the view's own ("view"), with the coverage as alpha
    (what :func:`~va_plugin.data.dataparsers.generators.read_normal_maps` reads)."""
    nominal = cameras.c2w[view, :, :3].numpy().astype(np.float64)
    frame = cameras.c2w[0 if normal_frame == "front" else view, :, :3].numpy().astype(np.float64)
    in_frame = camera_normals[..., :3] @ nominal.T @ frame  # world = R n; in the frame: R_f^T world
    gl = in_frame * np.array([1.0, -1.0, -1.0])
    alpha = camera_normals[..., 3:]
    return np.concatenate([np.where(alpha > 0, (gl + 1.0) / 2.0, 0.0), alpha], -1).astype(np.float32)


def score_generator_run(mesh_path: Path, scene_dir: Path, rig_to_training: dict, n_samples: int = 100_000,
                        resolution: int = 64) -> dict:
    """CD, volume IoU and F-score of a run's ``mesh.ply`` (training frame) against the scene's ``mesh.ply``
    brought into the training frame by the reader's ``rig_to_training`` (``x' = (x - centre) * scale``), both
    then scaled so the ground truth's bounding box has a longest side of 1 (the benchmark protocol)."""
    pred, truth = load_mesh(Path(mesh_path)), load_mesh(Path(scene_dir) / "mesh.ply")
    truth.apply_translation(-np.asarray(rig_to_training["centre"], np.float64))
    truth.apply_scale(float(rig_to_training["scale"]))
    unit = 1.0 / float(np.max(truth.bounds[1] - truth.bounds[0]))
    truth.apply_scale(unit)
    pred.apply_scale(unit)
    geo = geometry_metrics(pred, truth, n_samples=n_samples, threshold=FSCORE_THRESHOLD, resolution=resolution)
    return {"cd": geo["chamfer_distance"], "iou": geo["volume_iou"], "fscore": geo["f_score"],
            "geometry_params": geo["params"]}
