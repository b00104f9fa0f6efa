"""The Python API: reconstruct an object, or build a config, train, export and evaluate step by step.

Every command (``va-train``, ``va-recon``, ``va-batch``, ``va-demo``, ``va-export``, ``va-eval``) and every
benchmark runner goes through these functions, so a notebook gets exactly what the command line gets::

    import va_plugin

    result = va_plugin.reconstruct("strip.png", out="runs/chair")   # train, mesh, texture, turntable
    print(result.textured_mesh, result.seconds)

    config = va_plugin.build_config("neus", data="strip.png", steps=500, overrides={"seed": 1})
    run = va_plugin.train(config)                                    # the run folder
    files = va_plugin.export_mesh(run, export=va_plugin.ExportConfig(texture_size=512))
    scores = va_plugin.evaluate(run)                                  # scenes with ground truth only

A bad input or option raises :class:`~va_plugin.errors.VAError` (one line, before any work); Ctrl-C during
training saves a checkpoint and raises :class:`~va_plugin.engine.trainer.TrainingInterrupted` (a
``KeyboardInterrupt``); the same call with ``resume=True`` continues the run.
"""

from __future__ import annotations

import numbers
import os
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
import trimesh

from va_plugin.callbacks import TrainingCallback
from va_plugin.config import apply_override, validate_config
from va_plugin.data.dataparsers import FORMATS
from va_plugin.engine.loading import LoadedRun, load_run, locks_run, run_path
from va_plugin.engine.options import (
    QUALITIES,
    RECOMMENDED_METHOD,
    VIEW_COUNTS,
    input_dataparser,
    override_list,
    set_run_options,
)
from va_plugin.engine.sessions import (
    Progress,
    Stop,
    check_reconstruct_options,
    claimed_for_training,
    interrupt_after_training,
    quiet,
    resolve_config_paths,
    train_in_folder,
)
from va_plugin.engine.trainer import TrainerConfig, TrainingInterrupted
from va_plugin.errors import ConfigError
from va_plugin.eval.evaluate import check_evaluate_options, check_scorable, evaluate_run, has_ground_truth
from va_plugin.eval.mesh_render import textured_turntable
from va_plugin.export.config import ExportConfig, faces_option
from va_plugin.export.files import MESH_FILE, MeshFiles, mesh_outputs, write_meshes, write_summary
from va_plugin.export.render import check_render_options, render_test_views, render_turntable
from va_plugin.registry import discover_methods
from va_plugin.utils.arguments import check_hooks, check_kind, check_kinds
from va_plugin.utils.device import pick_device
from va_plugin.utils.files import write_json
from va_plugin.utils.memory import check_render_size, check_texture_memory, small_numpy_pages
from va_plugin.utils.paths import optional_user_path, user_path, within

__all__ = [
    "QUALITIES", "RECOMMENDED_METHOD", "VIEW_COUNTS", "ExportConfig", "LoadedRun", "MeshFiles", "Reconstruction",
    "TrainingInterrupted", "build_config", "evaluate", "export_mesh", "load_run", "reconstruct",
    "render", "train",
]

TURNTABLE_DIR = "turntable"
EVAL_FILE = "eval.json"
METRICS = ("cd", "iou", "fscore", "psnr", "ssim", "lpips")
"""The scores :func:`reconstruct` reports for an object with ground truth."""


def build_config(method: str = RECOMMENDED_METHOD, data: str | Path | None = None, *, preset: str | None = None,
                 steps: int | None = None, seed: int | None = None, device: str | None = None,
                 out: str | Path | None = None, views: int | str | None = None, elevation: float | None = None,
                 rig: str | Path | None = None, masks: str | Path | None = None, data_format: str = "auto",
                 overrides: Mapping[str, Any] | Iterable[str] | None = None, fov: float | None = None,
                 progress: bool = True) -> TrainerConfig:
    """The trainer config of ``method`` on ``data``: what ``va-train`` trains for the same options.

    ``data``: a generator output or scene folder (its format detected unless ``data_format`` names it);
    None: the method's own dataparser config, without reading any input (``va-train`` without ``--data``
    passes the embedded default scene of :func:`va_plugin.bench.scenes.default_scene`). ``preset``: a
    named variant of the method. ``views``: SyncDreamer strips; ``elevation``: SyncDreamer strips and rig
    formats with one elevation (SV3D, 4-view rigs, ...); ``fov``: perspective rig formats (degrees);
    ``rig``: a rig file (.json or .yaml, see docs/data.md) that describes the input's layout and cameras,
    a built-in rig's name (same as ``data_format``), or a Zero123++ version (v1.1, v1.2); ``masks``: a mask
    folder or image for generator inputs.
    ``overrides``: ``{"pipeline.model.eikonal_weight": 0.05}`` (or ``"key=value"`` strings, or ``__`` for the
    dots), applied last. ``out``: the run folder (default ``outputs/METHOD``). Paths are taken with ``~``
    expanded and resolved (:func:`~va_plugin.utils.paths.user_path`); the config holds them so."""
    check_kinds(method=(method, str), data_format=(data_format, str), progress=(progress, bool))
    check_kinds(optional=True, preset=(preset, str), rig=(rig, (str, Path)), elevation=(elevation, numbers.Real),
                fov=(fov, numbers.Real),
                seed=(seed, numbers.Integral), device=(device, (str, torch.device)))
    data, masks = optional_user_path(data, "data"), optional_user_path(masks, "masks")
    run_dir = user_path(out if out is not None else Path("outputs") / method, "out")
    methods = discover_methods()
    if method not in methods:
        raise ConfigError(f"unknown method {method!r}; known methods: {', '.join(methods)}")
    if data_format != "auto" and data_format not in FORMATS:
        raise ConfigError(f"unknown data format {data_format!r}; use auto or one of {', '.join(FORMATS)}")
    config = methods[method].make_config(preset)
    config.method_name = method
    config.preset_name = preset or "default"  # what the run folder's manifest names
    if data is not None:
        config.pipeline.datamanager.dataparser = input_dataparser(
            config.pipeline.datamanager.dataparser, data, data_format, rig,
            {"views": views, "elevation": elevation, "fov": fov, "masks": masks})
    config.output_dir = run_dir
    set_run_options(config, steps=steps, seed=seed, device=device, progress=progress)
    for assignment in override_list(overrides):
        apply_override(config, assignment)
    validate_config(config)
    pick_device(config.device)  # a device this machine lacks is refused here, before any work
    return config


def train(config: TrainerConfig, *, resume: bool = False, overwrite: bool = False,
          progress: Progress | None = None, on_message: Callable[[str], None] | None = None,
          stop: Stop = None, callbacks: Iterable[TrainingCallback] = ()) -> Path:
    """Train ``config`` into its run folder (``config.output_dir``) and return that folder.

    The folder must be new, empty, or a run of its own (see :mod:`va_plugin.engine.run_folder`);
    ``overwrite``: write into any folder (an earlier run there starts again). ``resume``: continue from the
    folder's newest checkpoint, when the method, preset, data and options are the run's own; without it, a
    folder that holds checkpoints is refused. ``progress(step, total, losses)`` is called after each step.
    ``on_message(line)`` gets the lines a user should see (the inputs found, a resume). ``callbacks``: more
    :class:`~va_plugin.callbacks.TrainingCallback` s for the trainer, after the model's own (a
    preview render every few hundred steps, say); one that changes no parameter and draws no random
    number leaves the training as it is. A run whose health guard intervened ends with a warning. Ctrl-C,
    SIGTERM or ``stop`` (a ``threading.Event`` set, or a callable returning True, polled between steps)
    end the step in progress, save a checkpoint and raise :class:`TrainingInterrupted`; ``resume=True``
    then continues exactly where it stopped."""
    check_kind("config", config, TrainerConfig)
    check_kinds(resume=(resume, bool), overwrite=(overwrite, bool), callbacks=(callbacks, Iterable))
    check_hooks(progress, stop, on_message)
    resolve_config_paths(config)
    with claimed_for_training(config, "train()", resume, overwrite, flag="--output-dir") as continues:
        train_in_folder(config, progress, on_message, stop=stop, callbacks=callbacks, resume=continues)
    return Path(config.output_dir)


@locks_run
def evaluate(run: str | Path | LoadedRun, *, scene: str | Path | None = None,
             mesh_resolution: int = ExportConfig.mesh_resolution, image_scale: float = 1.0,
             max_views: int | None = None, n_samples: int = 100_000,
             mesh: trimesh.Trimesh | None = None, render_dir: str | Path | None = None,
             output: str | Path | None = EVAL_FILE, progress: bool = False,
             device: str | None = None) -> dict[str, Any]:
    """Scores of a trained run against its scene's ground truth: PSNR, SSIM, LPIPS on the held-out views
    (rendered at ``image_scale``, at most ``max_views``), Chamfer distance, volume IoU and F-score of its
    mesh (``mesh``, or marching cubes at ``mesh_resolution``). ``scene``: a scene folder with
    ``scene.json`` other than the run's data. Written to ``RUN/eval.json`` (``output``; None: not
    written); ``render_dir`` also keeps the renders."""
    scene, render_dir = optional_user_path(scene, "scene"), optional_user_path(render_dir, "render_dir")
    check_kinds(n_samples=(n_samples, numbers.Integral), progress=(progress, bool))
    check_kind("output", output, str, os.PathLike, optional=True)
    check_evaluate_options(scene, mesh_resolution, image_scale, max_views)
    loaded = load_run(run, device)
    check_scorable(loaded, scene, image_scale)
    result = evaluate_run(loaded.pipeline, loaded.state, None if scene is None else Path(scene), mesh_resolution,
                          image_scale, max_views, n_samples, progress=progress, mesh=mesh,
                          render_dir=None if render_dir is None else Path(render_dir))
    if output is not None:
        write_json(within(output, loaded.path, "output"), result)
    return result


@locks_run
def render(run: str | Path | LoadedRun, out_dir: str | Path | None = None, *, scale: float = 1.0,
           max_views: int | None = None, frames: int = 24, turntable_resolution: int = 128,
           device: str | None = None, progress: bool = True) -> tuple[list[Path], list[Path]]:
    """Held-out views (or the training views when the run has none) and a turntable of the field, written
    to ``out_dir`` (default ``RUN/renders``); the held-out files and the turntable files. ``progress``:
    progress bars on stderr."""
    out_dir = optional_user_path(out_dir, "out_dir")
    check_render_options(scale, max_views, frames, turntable_resolution, progress)
    loaded = load_run(run, device)
    data = loaded.pipeline.datamanager
    cameras = (data.test if data.test is not None else data.train).cameras  # held-out views, or else training
    check_render_size(cameras.width, cameras.height, scale)
    out = loaded.path / "renders" if out_dir is None else out_dir
    held_out = render_test_views(loaded.pipeline, out / "test_views", scale=scale, max_views=max_views,
                                 progress=progress)
    turntable = render_turntable(loaded.pipeline.model, out / "turntable", n_frames=frames,
                                 resolution=turntable_resolution, progress=progress)
    return held_out, turntable


@dataclass
class Reconstruction:
    """What :func:`reconstruct` made: the files, the figures and the config it trained."""

    run_dir: Path
    mesh: Path
    """``RUN/mesh.ply``: the mesh with vertex colors."""
    textured_mesh: Path | None
    """``RUN/mesh.glb``: the mesh with its baked texture, upright unless ``frame="training"`` (None with
    ``texture=False``)."""
    turntable: Path | None
    """``RUN/turntable/turntable.mp4`` of the textured mesh (None without texture or frames)."""
    summary: Path
    """``RUN/summary.json``: everything below, as JSON."""
    seconds: float
    """Wall seconds of the call (training, mesh, texture, turntable, scores)."""
    train_seconds: float
    """Seconds of training, over every session of the run."""
    steps: int
    views: int
    """Training views."""
    masks: str
    """Where the object masks came from."""
    config: TrainerConfig
    scores: dict[str, float] = field(default_factory=dict)
    """Scores against ground truth (scene folders only; see :data:`METRICS`)."""
    resumed_from_step: int | None = None
    record: dict[str, Any] = field(default_factory=dict)
    """The summary as written to ``summary.json``."""
    files: MeshFiles | None = field(default=None, repr=False)
    """The meshes themselves (for pictures of them without reading the files back)."""
    textured_obj: Path | None = None
    """``RUN/mesh.obj`` (with ``mesh.mtl`` and ``mesh.png``): the same textured mesh as OBJ."""


def reconstruct(input: str | Path, out: str | Path | None = None, method: str = RECOMMENDED_METHOD,
                quality: str = "default", views: int | str = "all", steps: int | None = None,
                device: str = "auto", texture: bool | None = None, progress: Progress | None = None, *,
                seed: int | None = None, preset: str | None = None, masks: str | Path | None = None,
                elevation: float | None = None, rig: str | Path | None = None, data_format: str = "auto",
                fov: float | None = None, resume: bool = False, overwrite: bool = False,
                texture_size: int | None = None, mesh_resolution: int | None = None, turntable_frames: int = 36,
                fusion: str | None = None, threads: int = 0, faces: int | None = None, frame: str | None = None,
                export: ExportConfig | None = None, evaluate_options: Mapping[str, Any] | None = None,
                show_progress: bool = False, on_message: Callable[[str], None] | None = None,
                callbacks: Iterable[TrainingCallback] = (),
                overrides: Mapping[str, Any] | Iterable[str] | None = None, stop: Stop = None,
                **more_overrides: Any) -> Reconstruction:
    """A generator output (or scene folder) to a textured mesh, in one call: what ``va-recon`` does.

    Trains ``method`` (``quality``: ``fast``, ``default`` or ``accurate``; ``preset`` names any preset of
    the method instead) on ``views`` of the input, then writes ``RUN/mesh.ply``, the textured
    ``RUN/mesh.glb`` and ``RUN/mesh.obj`` and a turntable of it (unless ``texture`` is False), scores the
    run when the input has ground truth, and writes ``RUN/summary.json``. ``out``: the run folder (default
    ``outputs/recon/<input name>``); ``export`` and the keywords ``texture``, ``texture_size``,
    ``mesh_resolution``, ``fusion``, ``faces`` and ``frame``: the mesh and texture options as in
    :func:`export_mesh` (``mesh.glb`` and ``mesh.obj`` upright by default; ``mesh.ply`` in the training
    frame); ``evaluate_options``: keywords of :func:`evaluate` for the scores.
    ``progress(step, total, losses)``: called after each training step; ``show_progress``: progress bars on
    stderr; ``on_message(line)``: the stage lines; ``callbacks``: more training callbacks (see :func:`train`).
    ``overrides`` are config overrides as in :func:`build_config`, and so is any other keyword
    (``pipeline__model__eikonal_weight=0.05``).
    The run folder must be new, empty or a run of its own (``overwrite``: any folder; see :func:`train`).
    Interrupted (Ctrl-C, SIGTERM, or ``stop`` as in :func:`train`), it saves a checkpoint and raises
    :class:`TrainingInterrupted`; call again with ``resume=True`` to continue."""
    started = time.perf_counter()
    source = user_path(input, "input")
    run_dir = user_path(out if out is not None else Path("outputs") / "recon" / source.stem, "out")
    check_reconstruct_options(locals())
    export = ExportConfig.of(export, texture=texture, texture_size=texture_size, mesh_resolution=mesh_resolution,
                             fusion=fusion, faces=faces, frame=frame)
    export.validate()
    config = build_config(method, source, preset=QUALITIES[quality] if preset is None else preset, steps=steps,
                          seed=seed, device=device, out=run_dir, views=views, elevation=elevation, rig=rig,
                          masks=masks, data_format=data_format, fov=fov,
                          overrides=[*override_list(overrides), *override_list(more_overrides)],
                          progress=show_progress)
    config.num_threads = threads
    say = on_message or quiet
    with claimed_for_training(config, "reconstruct()", resume, overwrite, command="recon") as continues:
        if threads > 0:
            torch.set_num_threads(threads)

        def check_bake(trainer) -> None:
            if export.texture:
                check_texture_memory(export.texture_size, len(trainer.pipeline.datamanager.train))

        header = f"{method} ({quality if preset is None else 'preset ' + preset}) on {input} -> {run_dir}"
        resumed_from = train_in_folder(config, progress, say, before_training=check_bake, callbacks=callbacks,
                                       header=header, stop=stop, resume=continues)
        with interrupt_after_training(run_dir):
            loaded = load_run(run_dir, device)  # what va-export and va-eval see: the run as its checkpoint holds it
            say(f"extracting the mesh ({export.mesh_resolution}^3 grid)")
            if export.texture:
                say(f"UV-unwrapping the mesh and baking a {export.texture_size}^2 texture from the views")
            files = export_mesh(loaded, export=export, progress=show_progress)
            turntable = None
            if export.texture and turntable_frames:
                turntable = Path(textured_turntable(files.textured, run_dir / TURNTABLE_DIR, turntable_frames,
                                                    progress=show_progress))
            scores: dict[str, float] = {}
            if has_ground_truth(loaded):
                result = evaluate(loaded, mesh=files.mesh,
                                  **{"mesh_resolution": export.mesh_resolution, **(evaluate_options or {})})
                scores = {name: result[name] for name in METRICS if name in result}
            summary = write_summary(loaded, files, turntable, scores, resumed_from, started,
                                    input=str(source), method=method, quality=quality)
    record = summary[1]
    return Reconstruction(run_dir=run_dir, mesh=Path(files.path), textured_mesh=files.textured_mesh,
                          turntable=turntable, summary=summary[0], seconds=record["seconds"],
                          train_seconds=record["train_seconds"], steps=record["steps"], views=record["views"],
                          masks=record["masks"], config=config, scores=scores, resumed_from_step=resumed_from,
                          record=record, files=files, textured_obj=files.textured_obj)


@locks_run
@small_numpy_pages()
def export_mesh(run: str | Path | LoadedRun, *, texture: bool | None = None, resolution: int | None = None,
                texture_size: int | None = None, fusion: str | None = None,
                output: str | Path | Iterable[str | Path] | None = None,
                vertex_colors: str | Path | None = MESH_FILE, largest_component: bool = False,
                faces: int | None = None, frame: str | None = None, use_inconsistency: bool = False,
                harmonise: bool | None = None, progress: bool = False, device: str | None = None,
                overwrite: bool = False, max_faces: int | None = None,
                export: ExportConfig | None = None) -> MeshFiles:
    """The run's mesh: marching cubes of its field on a ``resolution``^3 grid, written with vertex colors
    to ``RUN/mesh.ply`` (``vertex_colors``: another name, None for none), and with ``texture`` also
    UV-unwrapped, baked from the input views and written to ``output`` (default both ``RUN/mesh.glb`` and
    ``RUN/mesh.obj`` with its ``.mtl`` and ``.png``; one path or several). ``export``: the mesh and texture
    options as one :class:`~va_plugin.export.config.ExportConfig` (which holds their defaults); the keywords of
    the same names override it (``resolution`` is its ``mesh_resolution``). ``faces``: the textured mesh's
    face count, by quadric decimation before the unwrap (0 keeps every face; a mesh with fewer faces is first
    extracted again on a finer grid, see :func:`~va_plugin.export.mesh.mesh_for_faces`); ``max_faces`` is
    its old name. ``frame``:
    ``upright`` (GLB and OBJ +Y up, standing on y = 0, centred on the vertical axis) or ``training``
    (as trained, +Z up); PLY always stays in the training frame. ``fusion``: ``robust`` or ``mean`` per
    texel; ``harmonise=False`` skips levelling the views' color gains. Relative file names are inside the
    run folder; an ``output`` file outside a run folder that exists is refused unless ``overwrite``."""
    export = ExportConfig.of(export, texture=texture, mesh_resolution=resolution, texture_size=texture_size,
                             fusion=fusion, faces=faces_option(faces, max_faces), frame=frame)
    export.validate(resolution_flag="--resolution")
    check_kinds(largest_component=(largest_component, bool), use_inconsistency=(use_inconsistency, bool),
                progress=(progress, bool), overwrite=(overwrite, bool))
    check_kinds(optional=True, output=(output, (str, os.PathLike, Iterable)),
                vertex_colors=(vertex_colors, (str, os.PathLike)), harmonise=(harmonise, bool))
    outs, plain = mesh_outputs(run_path(run), export, output, vertex_colors, overwrite)
    return write_meshes(load_run(run, device), export, outs, plain, largest_component, use_inconsistency,
                        harmonise, progress)
