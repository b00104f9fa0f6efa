"""The Python API: reconstruct an object, or build a config, train, export and evaluate step by step.

Every command (``va-train``, ``va-recon``, ``va-batch``, ``va-demo``, ``va-export``, ``va-eval``) and every
benchmark runner goes through these functions, so a notebook gets exactly what the command line gets::

    import va_plugin

    result = va_plugin.reconstruct("strip.png", out="runs/chair")   # train, mesh, texture, turntable
    print(result.textured_mesh, result.seconds)

    config = va_plugin.build_config("neus", data="strip.png", steps=500, overrides={"seed": 1})
    run = va_plugin.train(config)                                    # the run folder
    files = va_plugin.export_mesh(run, texture=True)
    scores = va_plugin.evaluate(run)                                  # scenes with ground truth only

A bad input or option raises :class:`~va_plugin.errors.VAError` (one line, before any work); Ctrl-C during
training saves a checkpoint and raises :class:`~va_plugin.engine.trainer.TrainingInterrupted` (a
``KeyboardInterrupt``); the same call with ``resume=True`` continues the run.
"""

from __future__ import annotations

import contextlib
import copy
import functools
import json
import math
import numbers
import os
import threading
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import torch
import trimesh

from va_plugin.callbacks import TrainingCallback
from va_plugin.config import apply_override, validate_config
from va_plugin.data.datamanager import MASK_PICTURE
from va_plugin.data.dataparsers import FORMATS, resolve_dataparser
from va_plugin.data.dataparsers.rigged import RigDataParserConfig
from va_plugin.data.dataparsers.transforms import TransformsDataParserConfig
from va_plugin.data.rigfile import builtin_rigs, is_rig_file
from va_plugin.engine.run_folder import check_output_file, claim_run_folder, writing_into_run
from va_plugin.engine.trainer import (
    TrainerConfig,
    TrainingInterrupted,
    checkpoint_step,
    list_checkpoints,
    load_checkpoint,
    schedule_steps_of,
    train_run,
)
from va_plugin.errors import CheckpointError, ConfigError, DataError
from va_plugin.eval.evaluate import evaluate_run, ground_truth_mesh_path
from va_plugin.eval.mesh_render import textured_turntable
from va_plugin.export.atlas import MAX_TEXTURE_FACES
from va_plugin.export.frame import check_frame, frame_applies, frame_record, frame_transform
from va_plugin.export.mesh import MESH_FORMATS, extract_mesh, write_mesh
from va_plugin.export.render import render_test_views, render_turntable
from va_plugin.export.texture import check_texture_size, texture_run_mesh
from va_plugin.export.writing import check_texture_output
from va_plugin.pipelines.base import Pipeline
from va_plugin.registry import discover_methods
from va_plugin.utils.arguments import check_hooks, check_kind, check_kinds
from va_plugin.utils.device import pick_device
from va_plugin.utils.files import write_atomic
from va_plugin.utils.memory import (
    check_batch_memory,
    check_image_side,
    check_mesh_resolution,
    check_render_size,
    check_texture_memory,
    small_numpy_pages,
)
from va_plugin.utils.paths import optional_user_path, user_path, within

__all__ = [
    "QUALITIES", "RECOMMENDED_METHOD", "VIEW_COUNTS", "LoadedRun", "MeshFiles", "Reconstruction",
    "TrainingInterrupted", "build_config", "evaluate", "export_mesh", "load_run", "reconstruct",
    "render", "train",
]

RECOMMENDED_METHOD = "neus"
QUALITIES = {"fast": "fast", "default": None, "accurate": "accurate"}
"""``quality`` -> the method's preset."""
VIEW_COUNTS = (4, 8, 12, 16)
"""SyncDreamer: the training view counts one can ask for (uniform in azimuth), besides ``"all"``."""
MESH_FILE = "mesh.ply"
TEXTURED_MESH_FILE = "mesh.glb"
TEXTURED_OBJ_FILE = "mesh.obj"
"""Written beside ``mesh.glb`` by default, with ``mesh.mtl`` and ``mesh.png``: the same textured mesh as OBJ."""
TURNTABLE_DIR = "turntable"
SUMMARY_FILE = "summary.json"
EVAL_FILE = "eval.json"
METRICS = ("cd", "iou", "fscore", "psnr", "ssim", "lpips")
"""The scores :func:`reconstruct` reports for an object with ground truth."""

# generator option -> (dataparser option, the formats that have it)
GENERATOR_OPTIONS = {"views": ("num_views", "syncdreamer"),
                     "elevation": ("elevation_deg", "syncdreamer and rig-format"),
                     "fov": ("fov_deg", "rig-format (perspective)"),
                     "rig": ("rig", "zero123pp"), "masks": ("masks", "generator")}
Progress = Callable[[int, int, dict[str, float]], None]
"""``progress(step, total, losses)``: called after every training step."""
Stop = threading.Event | Callable[[], bool] | None
"""``stop``: training stops at the next step boundary once the Event is set or the callable returns True."""


def _override_text(key: str, value: Any) -> str:
    """``key=value`` as ``--set`` reads it (lists as JSON, booleans as true/false)."""
    if isinstance(value, bool):
        value = "true" if value else "false"
    elif isinstance(value, (list, tuple)):
        value = json.dumps(list(value))
    return f"{key.replace('__', '.')}={value}"


def _override_list(overrides: Mapping[str, Any] | Iterable[str] | None) -> list[str]:
    check_kind("overrides", overrides, Mapping, Iterable, str, optional=True)
    if overrides is None:
        return []
    if isinstance(overrides, Mapping):
        return [_override_text(key, value) for key, value in overrides.items()]
    if isinstance(overrides, str):
        return [overrides]
    return list(overrides)


def _apply_generator_options(parser_config, given: dict[str, Any]) -> None:
    """Copy the generator options that were given onto the dataparser config (a dataclass), refusing ones
    it has no field for."""
    options = {f.name for f in fields(parser_config)}
    for name, (option, formats) in GENERATOR_OPTIONS.items():
        value = given.get(name)
        if value is None:
            continue
        if value == "all":  # every view the input has: the generators' parsers train on all by default
            if option in options:
                setattr(parser_config, option, max(VIEW_COUNTS))
            continue
        if option not in options or (name == "rig" and isinstance(parser_config, RigDataParserConfig)):
            raise ConfigError(f"--{name} applies to {formats} inputs only")
        setattr(parser_config, option, value)


def check_views(views: Any) -> Any:
    """``views``: one of :data:`VIEW_COUNTS`, ``"all"`` or None; anything else is refused."""
    if views is None or views == "all" or (isinstance(views, int) and not isinstance(views, bool)
                                           and views in VIEW_COUNTS):
        return views
    raise ConfigError(f"views {views!r} is not one of 4, 8, 12, 16 or all")


def split_rig_option(rig: str | Path | None, data_format: str) -> tuple[str | None, str | Path | None, str]:
    """``rig`` as ``(zero123pp version, rig file, data format)``: a rig file (.json, .yaml) is read as the
    input's layout, a built-in rig's name is its format, anything else is a Zero123++ version."""
    if rig is None:
        return None, None, data_format
    if is_rig_file(rig):
        return None, rig, data_format
    if str(rig) in builtin_rigs():
        if data_format not in ("auto", str(rig)):
            raise ConfigError(f"--rig {rig} and --data-format {data_format} disagree; give one of them")
        return None, None, str(rig)
    return str(rig), None, data_format


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
    config.preset_name = preset or "default"  # not a field: what the run folder's manifest names
    if data is not None:
        version, rig_file, data_format = split_rig_option(rig, data_format)
        config.pipeline.datamanager.dataparser = resolve_dataparser(data, data_format,
                                                                    config.pipeline.datamanager.dataparser,
                                                                    rig_file=optional_user_path(rig_file, "rig"))
        _apply_generator_options(config.pipeline.datamanager.dataparser,
                                 {"views": check_views(views), "elevation": elevation, "rig": version, "fov": fov,
                                  "masks": masks})
    config.output_dir = run_dir
    if steps is not None:
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise ConfigError(f"--steps must be at least 1, got {steps}")
        config.max_steps = steps
    if seed is not None:
        config.seed = seed
    if device is not None:
        config.device = device
    config.progress = progress
    for assignment in _override_list(overrides):
        apply_override(config, assignment)
    validate_config(config)
    pick_device(config.device)  # a device this machine lacks is refused here, before any work
    return config


def input_summary(pipeline: Pipeline, run_dir: Path) -> str | None:
    """One line about generator inputs (format, views, where the masks came from); None for scenes."""
    meta = pipeline.datamanager.train.metadata
    if "mask_source" not in meta:
        return None
    return (f"{meta['format']} input: {len(pipeline.datamanager.train)} training views, masks from the "
            f"{meta['mask_source']} (check {Path(run_dir) / MASK_PICTURE})")


def preset_of(config: TrainerConfig) -> str:
    """The preset a config was built from (``default`` for a config built by hand)."""
    return config.preset_name


def check_training_memory(config: TrainerConfig) -> None:
    """Refuse, before the views are read, a training batch that would not fit in memory (the views' own
    size is checked when they are loaded, before they are resized)."""
    check_batch_memory(config.pipeline.datamanager.rays_per_batch, config.pipeline.model.samples_per_ray())


def _train(config: TrainerConfig, progress: Progress | None, on_message: Callable[[str], None] | None,
           before_training: Callable[[Any], None] | None = None, header: str | None = None,
           stop: Stop = None, callbacks: Iterable[TrainingCallback] = (), resume: bool = False) -> int | None:
    """:func:`train`'s work in a claimed run folder; the step the run resumed from (None for a fresh run).
    ``header``: a line said once the data has loaded (bad input stays one line: the error alone).
    ``resume``: continue from the folder's checkpoints (what :func:`claim_run_folder` allowed)."""
    run_dir = Path(config.output_dir)
    say = on_message or _quiet
    trainer = config.setup()
    trainer.callbacks.extend(callbacks)
    for line in (header, input_summary(trainer.pipeline, run_dir)):
        if line:
            say(line)
    if before_training is not None:
        before_training(trainer)
    done = train_run(config, resume=resume, trainer=trainer, on_step=progress, stop=stop,
                     on_resume=lambda step: say(f"resuming {config.method_name} from step {step}"))
    health = done.trainer.guard.summary()
    if health:
        warnings.warn(health, stacklevel=3)
    return done.resumed_from


_TRAINING: dict[int, list] = {}
"""Thread id -> [the call training in it, whether another thread trained meanwhile]."""
_TRAINING_LOCK = threading.Lock()


@contextlib.contextmanager
def training_in_this_thread(call: str) -> Iterator[None]:
    """Mark ``call`` as training in this thread for the block. Two runs at once in two threads of one
    process share torch's global state (its random generator, its thread count), so neither gives the
    results it gives alone: each of them says so with a warning (the one starting second at once, the
    other when it ends)."""
    me = threading.get_ident()
    with _TRAINING_LOCK:
        nested = me in _TRAINING
        others = [entry for ident, entry in _TRAINING.items() if ident != me]
        if not nested:
            _TRAINING[me] = [call, bool(others)]
        for entry in others:
            entry[1] = True
    advice = ("torch's random generator and thread count are shared by the threads of a process, so its results "
              "differ from the same call run alone; run one at a time, or each in its own process (as va-batch "
              "does)")
    if others and not nested:
        warnings.warn(f"{call} started while {others[0][0]} trains in another thread: {advice}", stacklevel=4)
    try:
        yield
    finally:
        if not nested:
            with _TRAINING_LOCK:
                entry = _TRAINING.pop(me)
            if entry[1] and not others:
                warnings.warn(f"{call} trained while another call trained in another thread: {advice}",
                              stacklevel=4)


def _quiet(line: str) -> None:
    """The default ``on_message``: nothing is shown."""


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
    check_training_memory(config)
    with training_in_this_thread("train()"), \
            claim_run_folder(config, resume=resume, overwrite=overwrite, preset=preset_of(config),
                             flag="--output-dir") as continues:
        _train(config, progress, on_message, stop=stop, callbacks=callbacks, resume=continues)
    return Path(config.output_dir)


def resolve_config_paths(config: TrainerConfig) -> None:
    """The run folder and the input paths of ``config`` (one built by hand, say) made absolute, ``~``
    expanded, in place: every step of the run then reads and writes the same places."""
    config.output_dir = user_path(config.output_dir, "output_dir")
    parser = config.pipeline.datamanager.dataparser
    for name in ("data", "masks"):
        if getattr(parser, name, None) is not None:
            setattr(parser, name, user_path(getattr(parser, name), name))


@dataclass
class LoadedRun:
    """A run folder read back: its pipeline (trained weights loaded, eval mode) and newest checkpoint."""

    path: Path
    pipeline: Pipeline
    state: dict[str, Any]

    @property
    def config(self) -> TrainerConfig:
        return self.state["config_object"]

    def parts(self) -> tuple[Pipeline, dict[str, Any]]:
        """(pipeline, checkpoint state), for ``pipeline, state = load_run(run).parts()``."""
        return self.pipeline, self.state


def load_run(run: str | Path | LoadedRun, device: str | None = None) -> LoadedRun:
    """The run folder's pipeline with its newest readable checkpoint loaded (a :class:`LoadedRun` passes
    through as it is)."""
    if isinstance(run, LoadedRun):
        return run
    run = user_path(run, "run")
    state = load_checkpoint(run, map_location="cpu")
    config = state.get("config_object")
    if config is None:
        raise CheckpointError(f"{state['path']} carries no config; it was not written by va-train")
    bad = [name for name, value in state["model"].items()
           if isinstance(value, torch.Tensor) and value.is_floating_point() and not bool(value.isfinite().all())]
    if bad:
        raise CheckpointError(f"{state['path']} holds NaN or infinite values ({bad[0]}"
                              f"{' and more' if len(bad) > 1 else ''}): the run diverged; retrain it (or resume "
                              "from a checkpoint before the divergence)")
    config = copy.deepcopy(config)
    torch_device = pick_device(device if device is not None else "auto")
    pipeline = config.pipeline.setup(device=torch_device, schedule_steps=schedule_steps_of(config))
    try:
        pipeline.model.load_state_dict(state["model"])
    except RuntimeError as exc:
        raise CheckpointError(f"{state['path']} does not fit its own config ({str(exc).splitlines()[0]})") from None
    # the schedules of the run's last trained step, as the trainer left them (no parameter is touched)
    pipeline.model.restore_step(max(int(state["step"]) - 1, 0))
    pipeline.model.eval()
    return LoadedRun(run, pipeline, state)


@dataclass
class MeshFiles:
    """What :func:`export_mesh` wrote, and the meshes themselves."""

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


def check_faces(faces: int | None, texture: bool) -> None:
    """Refuse a face count that is not 0 (every face) or at least 4, or one given without a texture."""
    if faces is None:
        return
    if isinstance(faces, bool) or not isinstance(faces, int) or faces < 0 or 0 < faces < 4:
        raise ConfigError(f"--faces must be 0 (keep every face) or at least 4, got {faces}")
    if faces > MAX_FACES:
        raise ConfigError(f"--faces {faces} is more than a mesh here can have (the finest grid, "
                          f"{FACES_MAX_RESOLUTION}^3, gives at most about {MAX_FACES}); ask for at most {MAX_FACES}, "
                          "or 0 to keep every face of the extracted mesh")
    if not texture:
        raise ConfigError("--faces sets the face count of the textured mesh: it needs --texture (va-export mesh), "
                          "and no --no-texture (va-recon, va-batch)")


def faces_option(faces: int | None, max_faces: int | None) -> int | None:
    """``faces``, or ``max_faces`` (its old name, with a note); both given and different: ConfigError."""
    if max_faces is None:
        return faces
    if faces is not None and faces != max_faces:
        raise ConfigError(f"faces={faces} and max_faces={max_faces} disagree; max_faces is the old name of faces")
    warnings.warn("max_faces is now faces; the old name still works for now", stacklevel=3)
    return max_faces


def check_mesh_options(resolution: int, texture: bool = False, texture_size: int = 1024,
                       output: Path | list[Path] | None = None, faces: int | None = None,
                       frame: str = "upright") -> None:
    """Refuse mesh and texture options that cannot work, before any marching cubes (one line each)."""
    if resolution < 2:
        raise ConfigError(f"--resolution must be at least 2, got {resolution}")
    outputs = [] if output is None else [output] if isinstance(output, (str, Path)) else list(output)
    for path in outputs:
        if Path(path).suffix.lower() not in MESH_FORMATS:
            raise ConfigError(f"unknown mesh format {Path(path).suffix!r}; use one of {', '.join(MESH_FORMATS)}")
    if texture:
        check_texture_size(texture_size)
        for path in outputs:
            check_texture_output(Path(path))
    check_faces(faces, texture)
    check_frame(frame)
    check_mesh_resolution(resolution)


FACES_MAX_RESOLUTION = 384
"""Finest marching-cubes grid that :func:`mesh_for_faces` extracts to reach a ``faces`` count."""
MAX_FACES = 2_000_000
"""Most faces ``faces`` may ask for: a surface on the :data:`FACES_MAX_RESOLUTION` grid has about
2 pi R^2 faces when it fills the grid (0.93 million at 384), twice that when it is wrinkled; a larger count
could not be met, and would only cost the finest extraction before its warning."""
FACES_MARGIN = 1.15
"""How far past the asked face count the finer grid aims (a surface's faces grow as the grid squared)."""


def mesh_for_faces(model, mesh: trimesh.Trimesh, faces: int | None, resolution: int,
                   largest_component: bool) -> tuple[trimesh.Trimesh, int]:
    """The mesh to decimate to ``faces`` and its grid: ``mesh`` itself when it has at least that many faces;
    otherwise the field extracted again on a grid fine enough to have them (faces grow as the grid
    squared; at most :data:`FACES_MAX_RESOLUTION`, and only where it fits in memory). A mesh still short
    of ``faces`` is kept with a one-line warning."""
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


def _locks_run(function: Callable[..., Any]) -> Callable[..., Any]:
    """Hold the run folder's lock (:func:`~va_plugin.engine.run_folder.writing_into_run`) while ``function``
    writes into it; a run that another process is training or exporting is refused."""

    @functools.wraps(function)
    def locked(run: str | Path | LoadedRun, *args: Any, **kwargs: Any) -> Any:
        if not isinstance(run, LoadedRun):
            run = user_path(run, "run")
        with writing_into_run(run.path if isinstance(run, LoadedRun) else run):
            return function(run, *args, **kwargs)

    return locked


@_locks_run
@small_numpy_pages()
def export_mesh(run: str | Path | LoadedRun, *, texture: bool = True, resolution: int = 128,
                texture_size: int = 1024, fusion: str = "robust",
                output: str | Path | Iterable[str | Path] | None = None,
                vertex_colors: str | Path | None = MESH_FILE, largest_component: bool = False,
                faces: int | None = None, frame: str = "upright", use_inconsistency: bool = False,
                harmonise: bool | None = None, progress: bool = False, device: str | None = None,
                overwrite: bool = False, max_faces: int | None = None) -> MeshFiles:
    """The run's mesh: marching cubes of its field on a ``resolution``^3 grid, written with vertex colors
    to ``RUN/mesh.ply`` (``vertex_colors``: another name, None for none), and with ``texture`` also
    UV-unwrapped, baked from the input views and written to ``output`` (default both ``RUN/mesh.glb`` and
    ``RUN/mesh.obj`` with its ``.mtl`` and ``.png``; one path or several). ``faces``: the textured mesh's
    face count, by quadric decimation before the unwrap (default at most 40000; 0 keeps every face; a
    mesh with fewer faces is first extracted again on a finer grid, see :func:`mesh_for_faces`);
    ``max_faces`` is its old name. ``frame``:
    ``upright`` (GLB and OBJ +Y up, standing on y = 0, centred on the vertical axis) or ``training``
    (as trained, +Z up); PLY always stays in the training frame. ``fusion``: ``robust`` or ``mean`` per
    texel; ``harmonise=False`` skips levelling the views' color gains. Relative file names are inside the
    run folder; an ``output`` file outside a run folder that exists is refused unless ``overwrite``."""
    faces = faces_option(faces, max_faces)
    check_kinds(texture=(texture, bool), resolution=(resolution, numbers.Integral),
                texture_size=(texture_size, numbers.Integral), fusion=(fusion, str), frame=(frame, str),
                largest_component=(largest_component, bool), use_inconsistency=(use_inconsistency, bool),
                progress=(progress, bool), overwrite=(overwrite, bool))
    check_kinds(optional=True, output=(output, (str, os.PathLike, Iterable)),
                vertex_colors=(vertex_colors, (str, os.PathLike)), harmonise=(harmonise, bool))
    run_path = run.path if isinstance(run, LoadedRun) else user_path(run, "run")
    if output is None:
        outs = [run_path / TEXTURED_MESH_FILE, run_path / TEXTURED_OBJ_FILE] if texture else []
    else:
        outs = [within(o, run_path, "output") for o in ([output] if isinstance(output, (str, os.PathLike))
                                                        else output)]
    if vertex_colors is not None:
        vertex_colors = within(vertex_colors, run_path, "vertex_colors")
    check_mesh_options(resolution, texture, texture_size, outs, faces, frame)
    if texture and not outs:
        raise ConfigError("output names no file for the textured mesh")
    for path in [*outs, *([] if vertex_colors is None else [run_path / vertex_colors])]:
        check_output_file(path, run_path, overwrite)
    loaded = load_run(run, device)
    mesh = extract_mesh(loaded.pipeline.model, resolution=resolution, largest_component=largest_component,
                        with_color=vertex_colors is not None or not texture)
    files = MeshFiles(mesh)
    if vertex_colors is not None:
        files.path = write_mesh(mesh, run_path / vertex_colors, frame)
        if frame_applies(files.path):
            files.frame = frame_record(frame, frame_transform(mesh.vertices, frame))
    if texture:
        source, grid = mesh_for_faces(loaded.pipeline.model, mesh, faces, resolution, largest_component)
        files.textured, files.report, files.textured_paths = texture_run_mesh(
            loaded.pipeline, source, outs, texture_size, fusion, use_inconsistency, progress=progress,
            harmonise_views=harmonise, max_faces=MAX_TEXTURE_FACES if faces is None else faces, frame=frame,
            record={"mesh_resolution": grid})
        files.textured_source = (grid, len(source.faces))
        files.frame = frame_record(frame, frame_transform(files.textured.vertices, frame))
    return files


def write_json(path: Path, data: dict[str, Any]) -> Path:
    """Write JSON whole or not at all (a killed call leaves no half-written file)."""
    return write_atomic(path, json.dumps(data, indent=2))


def has_ground_truth(loaded: LoadedRun) -> bool:
    """Whether the run's scene can be scored: a scene folder with held-out views or a true mesh (a
    generator output's other views are generated too, so they are no ground truth)."""
    scene = isinstance(loaded.config.pipeline.datamanager.dataparser, TransformsDataParserConfig)
    return scene and (loaded.pipeline.datamanager.test is not None or ground_truth_mesh_path(loaded.pipeline)
                      is not None)


def check_evaluate_options(scene: str | Path | None, mesh_resolution: int, image_scale: float,
                           max_views: int | None = None) -> None:
    """Refuse evaluation options that cannot work, before anything is loaded (one line each)."""
    if mesh_resolution < 8 or image_scale <= 0:
        raise ConfigError("--mesh-resolution must be at least 8 and --image-scale positive")
    if max_views is not None and max_views < 1:
        raise ConfigError(f"--max-views must be at least 1, got {max_views}")
    if scene is not None and not (Path(scene) / "scene.json").is_file():
        raise ConfigError(f"{scene} holds no scene.json")
    check_mesh_resolution(mesh_resolution, "--mesh-resolution")


def check_scorable(loaded: LoadedRun, scene: str | Path | None = None) -> None:
    """Refuse a run with nothing to score: no held-out views and no ground-truth mesh (of ``scene``, or of
    the run's own data)."""
    if loaded.pipeline.datamanager.test is None and \
            ground_truth_mesh_path(loaded.pipeline, None if scene is None else Path(scene)) is None:
        data = loaded.config.pipeline.datamanager.dataparser.data
        raise DataError(f"nothing to score in {loaded.path}: its data {data} has no held-out views and no "
                        "ground-truth mesh; pass --scene with a scene folder that has them")


@_locks_run
def evaluate(run: str | Path | LoadedRun, *, scene: str | Path | None = None, mesh_resolution: int = 128,
             image_scale: float = 1.0, max_views: int | None = None, n_samples: int = 100_000,
             mesh: trimesh.Trimesh | None = None, render_dir: str | Path | None = None,
             output: str | Path | None = EVAL_FILE, progress: bool = False,
             device: str | None = None) -> dict[str, Any]:
    """Scores of a trained run against its scene's ground truth: PSNR, SSIM, LPIPS on the held-out views
    (rendered at ``image_scale``, at most ``max_views``), Chamfer distance, volume IoU and F-score of its
    mesh (``mesh``, or marching cubes at ``mesh_resolution``). ``scene``: a scene folder with
    ``scene.json`` other than the run's data. Written to ``RUN/eval.json`` (``output``; None: not
    written); ``render_dir`` also keeps the renders."""
    scene, render_dir = optional_user_path(scene, "scene"), optional_user_path(render_dir, "render_dir")
    check_kinds(mesh_resolution=(mesh_resolution, numbers.Integral), image_scale=(image_scale, numbers.Real),
                n_samples=(n_samples, numbers.Integral), progress=(progress, bool))
    check_kinds(optional=True, max_views=(max_views, numbers.Integral), output=(output, (str, os.PathLike)))
    check_evaluate_options(scene, mesh_resolution, image_scale, max_views)
    loaded = load_run(run, device)
    check_scorable(loaded, scene)
    if loaded.pipeline.datamanager.test is not None:
        cameras = loaded.pipeline.datamanager.test.cameras
        check_render_size(cameras.width, cameras.height, image_scale, "--image-scale")
    result = evaluate_run(loaded.pipeline, loaded.state, None if scene is None else Path(scene), mesh_resolution,
                          image_scale, max_views, n_samples, progress=progress, mesh=mesh,
                          render_dir=None if render_dir is None else Path(render_dir))
    if output is not None:
        write_json(within(output, loaded.path, "output"), result)
    return result


@_locks_run
def render(run: str | Path | LoadedRun, out_dir: str | Path | None = None, *, scale: float = 1.0,
           max_views: int | None = None, frames: int = 24, turntable_resolution: int = 128,
           device: str | None = None, progress: bool = True) -> tuple[list[Path], list[Path]]:
    """Held-out views (or the training views when the run has none) and a turntable of the field, written
    to ``out_dir`` (default ``RUN/renders``); the held-out files and the turntable files. ``progress``:
    progress bars on stderr."""
    out_dir = optional_user_path(out_dir, "out_dir")
    check_kinds(scale=(scale, numbers.Real), frames=(frames, numbers.Integral),
                turntable_resolution=(turntable_resolution, numbers.Integral), progress=(progress, bool))
    check_kind("max_views", max_views, numbers.Integral, optional=True)
    if scale <= 0 or frames < 1 or turntable_resolution < 2:
        raise ConfigError("--scale must be positive, --frames at least 1 and --turntable-resolution at least 2")
    loaded = load_run(run, device)
    test = loaded.pipeline.datamanager.test
    views = test if test is not None else loaded.pipeline.datamanager.train
    check_render_size(views.cameras.width, views.cameras.height, scale)
    check_image_side(turntable_resolution, "--turntable-resolution")
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
                device: str = "auto", texture: bool = True, progress: Progress | None = None, *,
                seed: int | None = None, preset: str | None = None, masks: str | Path | None = None,
                elevation: float | None = None, rig: str | Path | None = None, data_format: str = "auto",
                fov: float | None = None, resume: bool = False, overwrite: bool = False, texture_size: int = 1024,
                mesh_resolution: int = 128,
                turntable_frames: int = 36, fusion: str = "robust", threads: int = 0,
                faces: int | None = None, frame: str = "upright",
                evaluate_options: Mapping[str, Any] | None = None,
                show_progress: bool = False, on_message: Callable[[str], None] | None = None,
                callbacks: Iterable[TrainingCallback] = (),
                overrides: Mapping[str, Any] | Iterable[str] | None = None, stop: Stop = None,
                **more_overrides: Any) -> Reconstruction:
    """A generator output (or scene folder) to a textured mesh, in one call: what ``va-recon`` does.

    Trains ``method`` (``quality``: ``fast``, ``default`` or ``accurate``; ``preset`` names any preset of
    the method instead) on ``views`` of the input, then writes ``RUN/mesh.ply``, the textured
    ``RUN/mesh.glb`` and ``RUN/mesh.obj`` and a turntable of it (unless ``texture`` is False), scores the
    run when the input has ground truth, and writes ``RUN/summary.json``. ``out``: the run folder (default
    ``outputs/recon/<input name>``); ``faces`` and ``frame``: as in :func:`export_mesh` (``mesh.glb`` and
    ``mesh.obj`` upright by default; ``mesh.ply`` in the training frame); ``evaluate_options``: keywords of
    :func:`evaluate` for the scores.
    ``progress(step, total, losses)``: called after each training step; ``show_progress``: progress bars on
    stderr; ``on_message(line)``: the stage lines; ``callbacks``: more training callbacks (see
    :func:`train`). ``overrides`` are config overrides as in
    :func:`build_config`, and so is any other keyword (``pipeline__model__eikonal_weight=0.05``).
    The run folder must be new, empty or a run of its own (``overwrite``: any folder; see :func:`train`).
    Interrupted (Ctrl-C, SIGTERM, or ``stop`` as in :func:`train`), it saves a checkpoint and raises
    :class:`TrainingInterrupted`; call again with ``resume=True`` to continue."""
    started = time.perf_counter()
    source = user_path(input, "input")
    run_dir = user_path(out if out is not None else Path("outputs") / "recon" / source.stem, "out")
    check_reconstruct_kinds(locals())
    if quality not in QUALITIES:
        raise ConfigError(f"quality {quality!r} is not one of {', '.join(QUALITIES)}")
    if not source.exists():
        raise ConfigError(f"input not found: {source}")
    if texture:
        check_texture_size(texture_size)
    check_faces(faces, texture)
    check_frame(frame)
    if mesh_resolution < 8:
        raise ConfigError(f"--mesh-resolution must be at least 8, got {mesh_resolution}")
    if turntable_frames < 0:
        raise ConfigError(f"--turntable-frames must be 0 or more, got {turntable_frames}")
    check_mesh_resolution(mesh_resolution, "--mesh-resolution")
    config = build_config(method, source, preset=QUALITIES[quality] if preset is None else preset, steps=steps,
                          seed=seed, device=device, out=run_dir, views=views, elevation=elevation, rig=rig,
                          masks=masks, data_format=data_format, fov=fov,
                          overrides=[*_override_list(overrides), *_override_list(more_overrides)],
                          progress=show_progress)
    config.num_threads = threads
    check_training_memory(config)
    say = on_message or _quiet
    with training_in_this_thread("reconstruct()"), \
            claim_run_folder(config, resume=resume, overwrite=overwrite, preset=preset_of(config),
                             command="recon") as continues:
        if threads > 0:
            torch.set_num_threads(threads)

        def check_bake(trainer) -> None:
            if texture:
                check_texture_memory(texture_size, len(trainer.pipeline.datamanager.train))

        resumed_from = _train(config, progress, say, before_training=check_bake, callbacks=callbacks,
                              header=f"{method} ({quality if preset is None else 'preset ' + preset}) on {input} "
                                     f"-> {run_dir}", stop=stop, resume=continues)
        with interrupt_after_training(run_dir):
            loaded = load_run(run_dir, device)  # what va-export and va-eval see: the run as its checkpoint holds it
            say(f"extracting the mesh ({mesh_resolution}^3 grid)")
            if texture:
                say(f"UV-unwrapping the mesh and baking a {texture_size}^2 texture from the views")
            files = export_mesh(loaded, texture=texture, resolution=mesh_resolution, texture_size=texture_size,
                                fusion=fusion, faces=faces, frame=frame, progress=show_progress)
            turntable = None
            if texture and turntable_frames:
                turntable = Path(textured_turntable(files.textured, run_dir / TURNTABLE_DIR, turntable_frames,
                                                    progress=show_progress))
            scores: dict[str, float] = {}
            if has_ground_truth(loaded):
                result = evaluate(loaded, mesh=files.mesh,
                                  **{"mesh_resolution": mesh_resolution, **(evaluate_options or {})})
                scores = {name: result[name] for name in METRICS if name in result}
            summary = _write_summary(loaded, files, turntable, scores, resumed_from, started,
                                     input=str(source), method=method, quality=quality)
    record = summary[1]
    return Reconstruction(run_dir=run_dir, mesh=Path(files.path), textured_mesh=files.textured_mesh,
                          turntable=turntable, summary=summary[0], seconds=record["seconds"],
                          train_seconds=record["train_seconds"], steps=record["steps"], views=record["views"],
                          masks=record["masks"], config=config, scores=scores, resumed_from_step=resumed_from,
                          record=record, files=files, textured_obj=files.textured_obj)


class InterruptedAfterTraining(TrainingInterrupted):
    """Ctrl-C or SIGTERM after training ended (during the mesh, the texture, the turntable or the scores):
    the trained run is whole in its last checkpoint, and the same call with ``resume=True`` skips the
    training and does the rest."""

    def __init__(self, step: int, checkpoint: Path | None) -> None:
        super().__init__(step, checkpoint, saved=True, cause="after training")
        self.args = (f"interrupted after training (the run is kept: step {step}, {checkpoint})",)


@contextlib.contextmanager
def interrupt_after_training(run_dir: Path) -> Iterator[None]:
    """Turn an interrupt of the block (the work after training) into :class:`InterruptedAfterTraining`."""
    try:
        yield
    except TrainingInterrupted:
        raise
    except KeyboardInterrupt:
        kept = list_checkpoints(run_dir)
        raise InterruptedAfterTraining(checkpoint_step(kept[-1]) if kept else 0, kept[-1] if kept else None) from None


def check_reconstruct_kinds(given: Mapping[str, Any]) -> None:
    """Refuse, before any work, an argument of :func:`reconstruct` of the wrong kind (``given``: its
    arguments by name)."""
    check_kinds(**{name: (given[name], kinds) for name, kinds in (
        ("method", str), ("quality", str), ("data_format", str), ("fusion", str), ("frame", str),
        ("texture", bool), ("resume", bool), ("overwrite", bool), ("show_progress", bool),
        ("texture_size", numbers.Integral), ("mesh_resolution", numbers.Integral),
        ("turntable_frames", numbers.Integral), ("threads", numbers.Integral), ("callbacks", Iterable))})
    check_kinds(optional=True, **{name: (given[name], kinds) for name, kinds in (
        ("evaluate_options", Mapping), ("steps", numbers.Integral), ("faces", numbers.Integral))})
    check_hooks(given["progress"], given["stop"], given["on_message"])


def _write_summary(loaded: LoadedRun, files: MeshFiles, turntable: Path | None, scores: dict[str, float],
                   resumed_from: int | None, started: float, **head: Any) -> tuple[Path, dict[str, Any]]:
    """``RUN/summary.json`` of :func:`reconstruct`: its path and its record."""
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
