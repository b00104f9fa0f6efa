"""Evaluating a trained run on its scene: the paper's image metrics on held-out views and the
geometry metrics of its mesh against the ground truth."""

from __future__ import annotations

import json
import numbers
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from va_plugin.data.dataparsers.transforms import TransformsDataParserConfig
from va_plugin.engine.loading import LoadedRun
from va_plugin.errors import ConfigError, DataError
from va_plugin.eval.geometry import geometry_metrics
from va_plugin.eval.image import SSIM_WINDOW, psnr, ssim
from va_plugin.eval.lpips import MIN_SIDE, LPIPSWeightsMissing, lpips, weight_paths
from va_plugin.export.config import MIN_MESH_RESOLUTION, ExportConfig
from va_plugin.export.mesh import extract_mesh
from va_plugin.export.render import held_out_views, write_pair
from va_plugin.utils.arguments import check_kind, check_kinds
from va_plugin.utils.memory import check_mesh_resolution, check_render_size

FSCORE_THRESHOLD = 0.02
"""F-score distance threshold in world units (objects fit a unit box): 2% of the object's size."""


def ground_truth_mesh_path(pipeline, scene_dir: Path | None = None) -> Path | None:
    """The scene's ground-truth mesh (``scene.json``'s "mesh" entry), or None when it has none."""
    train = pipeline.datamanager.train
    if scene_dir is None:
        json_path = train.metadata.get("json")
        if json_path is None:
            return None
        scene_dir = Path(json_path).parent
    scene_file = Path(scene_dir) / "scene.json"
    if not scene_file.is_file():
        return None
    entry = json.loads(scene_file.read_text()).get("mesh")
    return None if entry is None else Path(scene_dir) / entry


def load_mesh(path: Path) -> trimesh.Trimesh:
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many kinds of errors for bad files
        raise DataError(f"cannot read mesh {path} ({type(exc).__name__})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise DataError(f"mesh {path} has no faces")
    return mesh


def image_metrics(pipeline, image_scale: float = 1.0, max_views: int | None = None, use_lpips: bool = True,
                  progress: bool = True, render_dir: Path | None = None, render_fn=None) -> dict[str, Any]:
    """Mean PSNR, SSIM and LPIPS over the held-out views, rendered on the canonical path (or by
    ``render_fn(cameras, index)``, see :func:`held_out_views`); with ``render_dir`` each view is also
    written there as ``view_XXX.png`` (render | ground truth). Views too small for SSIM (11 px) or LPIPS
    (31 px) are scored without them, with a warning."""
    test = pipeline.datamanager.test
    if test is None:
        return {}
    if use_lpips:
        weight_paths()  # raises LPIPSWeightsMissing before any view is rendered
    scores: dict[str, list] = {"psnr": [], "ssim": [], "lpips": []}
    size = None
    for i, render, target in held_out_views(pipeline, image_scale, max_views, progress, desc="evaluating views",
                                              render_fn=render_fn):
        side = min(render.shape[:2])
        scores["psnr"].append(psnr(render, target))
        if side >= SSIM_WINDOW:
            scores["ssim"].append(ssim(render, target))
        if use_lpips and side >= MIN_SIDE:
            scores["lpips"].append(lpips(render, target))
        if render_dir is not None:
            write_pair(render_dir, i, render, target)
        size = render.shape[:2]
    if size is not None and min(size) < MIN_SIDE and (use_lpips or min(size) < SSIM_WINDOW):
        warnings.warn(f"held-out views of {size[1]}x{size[0]} px are too small for "
                      f"{'SSIM and LPIPS' if min(size) < SSIM_WINDOW else 'LPIPS'} (at least {SSIM_WINDOW} and "
                      f"{MIN_SIDE} px); scored without them", stacklevel=2)
    out: dict[str, Any] = {k: float(np.mean(v)) for k, v in scores.items() if v}
    out["image_params"] = {"views": len(scores["psnr"]), "width": None if size is None else int(size[1]),
                           "height": None if size is None else int(size[0]), "background": list(test.background)}
    return out


def evaluate_run(pipeline, state: dict[str, Any], scene_dir: Path | None = None,
                 mesh_resolution: int = ExportConfig.mesh_resolution,
                 image_scale: float = 1.0, max_views: int | None = None, n_samples: int = 100_000,
                 progress: bool = True, mesh: trimesh.Trimesh | None = None,
                 render_dir: Path | None = None) -> dict[str, Any]:
    """All metrics of a trained run: psnr, ssim, lpips, cd, iou, fscore, plus timing and parameters.
    ``mesh``: the run's mesh if already extracted; ``render_dir``: see :func:`image_metrics`."""
    started = time.perf_counter()
    result: dict[str, Any] = {"method": state.get("method_name"), "steps": int(state["step"]),
                              "train_seconds": float(state.get("train_seconds", 0.0))}
    try:
        result.update(image_metrics(pipeline, image_scale, max_views, use_lpips=True, progress=progress,
                                    render_dir=render_dir))
    except LPIPSWeightsMissing as exc:
        result.update(image_metrics(pipeline, image_scale, max_views, use_lpips=False, progress=progress,
                                    render_dir=render_dir))
        result["lpips_missing"] = str(exc)
    gt_path = ground_truth_mesh_path(pipeline, scene_dir)
    if gt_path is not None:
        pred = mesh if mesh is not None else extract_mesh(pipeline.model, resolution=mesh_resolution, with_color=False)
        geo = geometry_metrics(pred, load_mesh(gt_path), n_samples=n_samples, threshold=FSCORE_THRESHOLD)
        result.update({"cd": geo["chamfer_distance"], "iou": geo["volume_iou"], "fscore": geo["f_score"],
                       "geometry_params": {**geo["params"], "mesh_resolution": mesh_resolution,
                                           "ground_truth": str(gt_path)}})
    result["eval_seconds"] = round(time.perf_counter() - started, 2)
    return result


def has_ground_truth(loaded: LoadedRun) -> bool:
    """Whether the run's scene can be scored: a scene folder with held-out views or a true mesh (a
    generator output's other views are generated too, so they are no ground truth)."""
    scene = isinstance(loaded.config.pipeline.datamanager.dataparser, TransformsDataParserConfig)
    return scene and (loaded.pipeline.datamanager.test is not None or ground_truth_mesh_path(loaded.pipeline)
                      is not None)


def check_evaluate_options(scene: str | Path | None, mesh_resolution: int, image_scale: float,
                           max_views: int | None = None) -> None:
    """Refuse evaluation options that cannot work, before anything is loaded (one line each)."""
    check_kinds(mesh_resolution=(mesh_resolution, numbers.Integral), image_scale=(image_scale, numbers.Real))
    check_kind("max_views", max_views, numbers.Integral, optional=True)
    if mesh_resolution < MIN_MESH_RESOLUTION or image_scale <= 0:
        raise ConfigError(f"--mesh-resolution must be at least {MIN_MESH_RESOLUTION} and --image-scale positive")
    if max_views is not None and max_views < 1:
        raise ConfigError(f"--max-views must be at least 1, got {max_views}")
    if scene is not None and not (Path(scene) / "scene.json").is_file():
        raise ConfigError(f"{scene} holds no scene.json")
    check_mesh_resolution(mesh_resolution, "--mesh-resolution")


def check_scorable(loaded: LoadedRun, scene: str | Path | None = None, image_scale: float | None = None) -> None:
    """Refuse a run with nothing to score: no held-out views and no ground-truth mesh (of ``scene``, or of
    the run's own data); with ``image_scale``, also held-out views too large to render at that scale."""
    test = loaded.pipeline.datamanager.test
    if test is None and ground_truth_mesh_path(loaded.pipeline, None if scene is None else Path(scene)) is None:
        data = loaded.config.pipeline.datamanager.dataparser.data
        raise DataError(f"nothing to score in {loaded.path}: its data {data} has no held-out views and no "
                        "ground-truth mesh; pass --scene with a scene folder that has them")
    if test is not None and image_scale is not None:
        check_render_size(test.cameras.width, test.cameras.height, image_scale, "--image-scale")
