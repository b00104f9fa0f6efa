"""Pictures of what the view-adaptive renderer learned, written to the run folder.

- ``attention.png`` / ``attention.json``: the n x n attention matrix averaged over surface samples
  (row i: how much view i's fused feature draws on each view j).
- ``inconsistency.png`` / ``inconsistency.json``: per training view, |own-branch render - canonical
  render|, scored against the injected errors on a benchmark scene.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from va_plugin.data.images import read_image, write_image
from va_plugin.export.inconsistency import inconsistency_maps

MIN_FULL_SCALE = 1e-3
"""Smallest full scale of the inconsistency picture's color map (0 .. the maps' 99.5th percentile)."""
ERROR_THRESHOLD = 0.05
"""A pixel counts as perturbed when the input differs from its clean render by more than this (mean RGB)."""


def _colorize(values: np.ndarray, vmax: float) -> np.ndarray:
    """Float RGB in [0, 1] of ``values / vmax`` under the inferno color map."""
    scaled = (np.clip(values / max(vmax, 1e-8), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return cv2.applyColorMap(scaled, cv2.COLORMAP_INFERNO)[:, :, ::-1].astype(np.float32) / 255.0


def attention_picture(matrix: np.ndarray, cell: int = 64) -> np.ndarray:
    """A labelled heat map (uint8 RGB) of an n x n row-stochastic matrix: rows are the querying view."""
    n = matrix.shape[0]
    margin = 28
    heat = cv2.resize(_colorize(matrix, 1.0), (n * cell, n * cell), interpolation=cv2.INTER_NEAREST)
    canvas = np.full((n * cell + margin, n * cell + margin, 3), 255, np.uint8)
    canvas[margin:, margin:] = (heat * 255.0 + 0.5).astype(np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    small = 0.35 if cell < 48 else 0.45
    for i in range(n):
        cv2.putText(canvas, str(i), (margin + i * cell + cell // 2 - 4, 18), font, 0.45, (0, 0, 0), 1)
        cv2.putText(canvas, str(i), (6, margin + i * cell + cell // 2 + 4), font, 0.45, (0, 0, 0), 1)
        for j in range(n):
            value = float(matrix[i, j])
            ink = (0, 0, 0) if value > 0.6 else (255, 255, 255)
            cv2.putText(canvas, f"{value:.2f}", (margin + j * cell + 4, margin + i * cell + cell // 2 + 4),
                        font, small, ink, 1)
    return canvas


def write_attention(field, run_dir: Path) -> Path | None:
    """``attention.png`` and ``attention.json`` from the field's running average (None before fusion trained)."""
    matrix = field.attention_matrix()
    if matrix is None:
        return None
    matrix = matrix.numpy()
    run_dir = Path(run_dir)
    (run_dir / "attention.json").write_text(json.dumps(
        {"rows_query_view_cols_key_view": matrix.round(5).tolist(),
         "self_weight_mean": float(np.diag(matrix).mean()), "uniform": 1.0 / matrix.shape[0]}, indent=2))
    cell = 64 if matrix.shape[0] <= 8 else 40
    write_image(run_dir / "attention.png", attention_picture(matrix, cell))
    return run_dir / "attention.png"


def injected_error_maps(scene_dir: Path, size: tuple) -> list[np.ndarray] | None:
    """For a benchmark scene, per training view |input - clean render| (mean over RGB, on white) at
    ``size`` = (width, height); None for other data."""
    scene_dir = Path(scene_dir)
    info_path, frames_path = scene_dir / "scene.json", scene_dir / "transforms_train.json"
    if not (info_path.exists() and frames_path.exists()):
        return None
    train_views = json.loads(info_path.read_text()).get("train_views")
    frames = json.loads(frames_path.read_text()).get("frames", [])
    if not train_views or len(train_views) != len(frames):
        return None
    maps = []
    for view, frame in zip(train_views, frames):
        clean_path = scene_dir / "images" / f"clean_{view:03d}.png"
        input_path = scene_dir / frame["file_path"]
        if not input_path.suffix:
            input_path = input_path.with_suffix(".png")
        if not (clean_path.exists() and input_path.exists()):
            return None
        pair = []
        for path in (input_path, clean_path):
            image = read_image(path)
            if image.shape[2] == 4:  # composite on white, as training does by default
                image = image[:, :, :3] * image[:, :, 3:] + (1.0 - image[:, :, 3:])
            pair.append(cv2.resize(image[:, :, :3], size, interpolation=cv2.INTER_AREA))
        maps.append(np.abs(pair[0] - pair[1]).mean(-1))
    return maps


def overlap_scores(predicted: np.ndarray, injected: np.ndarray, threshold: float = ERROR_THRESHOLD
                   ) -> dict[str, float | None]:
    """How well an inconsistency map points at the injected errors: ``precision_top10`` (share of its
    top-10% pixels that were perturbed), ``chance`` (share of perturbed pixels) and ``pearson`` (None
    for a constant map)."""
    p, e = predicted.reshape(-1).astype(np.float64), injected.reshape(-1).astype(np.float64)
    perturbed = e > threshold
    k = max(1, round(0.1 * p.size))
    top = np.argpartition(-p, k - 1)[:k]
    pearson = float(np.corrcoef(p, e)[0, 1]) if p.std() > 0 and e.std() > 0 else None  # undefined: flat map
    return {"precision_top10": float(perturbed[top].mean()), "chance": float(perturbed.mean()),
            "pearson": pearson}


def write_inconsistency(pipeline, run_dir: Path, scale: float = 0.5, scene_dir: Path | None = None,
                        progress: bool = False) -> Path:
    """``inconsistency.png`` (one row per training view: input | own render | canonical render | map)
    and ``inconsistency.json`` (per-view mean of the map, and overlap with injected errors if known)."""
    run_dir = Path(run_dir)
    views = inconsistency_maps(pipeline, scale=scale, progress=progress)
    height, width = views[0]["map"].shape
    injected = injected_error_maps(scene_dir, (width, height)) if scene_dir is not None else None
    full_scale = max(float(np.percentile(np.stack([v["map"] for v in views]), 99.5)), MIN_FULL_SCALE)
    rows, summary = [], []
    for i, v in enumerate(views):
        entry = {"view": i, "mean_abs_difference": float(v["map"].mean()), "max": float(v["map"].max())}
        if injected is not None:
            entry.update(overlap_scores(v["map"], injected[i]))
            entry["injected_mean"] = float(injected[i].mean())
        summary.append(entry)
        rows.append(np.concatenate([v["input"], v["own"], v["canonical"], _colorize(v["map"], full_scale)], 1))
    write_image(run_dir / "inconsistency.png", np.concatenate(rows, 0))
    record = {"columns": ["input", "render with own branch", "canonical render",
                          "|own - canonical| (inferno, 0 .. full_scale)"],
              "full_scale": full_scale, "scale": scale, "views": summary}
    (run_dir / "inconsistency.json").write_text(json.dumps(record, indent=2))
    return run_dir / "inconsistency.png"


def write_diagnostics(pipeline, run_dir: Path, scale: float = 0.5, progress: bool = False) -> list[Path]:
    """Both pictures for a view-adaptive run (nothing for other fields); returns what was written."""
    field = pipeline.model.field
    if not field.has_view_branches:
        return []
    Path(run_dir).mkdir(parents=True, exist_ok=True)
    written = []
    attention = write_attention(field, run_dir)
    if attention is not None:
        written.append(attention)
    if field.branches_active():
        scene_dir = pipeline.datamanager.config.dataparser.data
        written.append(write_inconsistency(pipeline, run_dir, scale, scene_dir, progress))
    return written
