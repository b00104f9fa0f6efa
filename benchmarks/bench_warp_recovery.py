"""How much of a benchmark scene's injected image-space error a run's per-view image warps recovered.

A GSO benchmark scene makes training view i by reading the clean render at ``coords_i(p)`` for each
pixel ``p`` (the ``pose`` kind's map through the mesh's depth, composed with the ``geometric`` kind's
smooth 2-D displacement; see ``GSOSource.perturbed``). The warp that undoes it reads the input at
``p + s_i(p)`` with ``s_i(p) = coords_i^-1(p) - p``, about ``-(coords_i(p) - p)`` for errors of a few
pixels: that is what ``pipeline.model.view_warp`` can learn. For each run and perturbed training view,
over the view's object pixels (input mask > 0.5), this prints:

- injected: RMS length of the ideal shift, pixels;
- left: RMS length of (learned - ideal); "recovered" is ``1 - left / injected`` (1: exact, 0: no better
  than no warp, below 0: worse than none);
- floor: what the best shift grid of the run's size (least squares) would leave, the part of the error a
  warp of that grid cannot express;
- along: the learned shift's component along the ideal one, ``<s, t> / <t, t>`` (1: the right direction
  and size; 0: unrelated).

    python benchmarks/bench_warp_recovery.py RUN [RUN ...] [--json OUT.json]
    python benchmarks/bench_warp_recovery.py --against-clean SCENE [SCENE ...] [--json OUT.json]

With ``--against-clean`` the arguments are benchmark scene folders, and each perturbed training view is
registered by a fresh warp (5x5 grid, no penalty, 300 Adam steps at lr 1e-3 on colour and alpha) against
its own clean render (``images/clean_XXX.png``), the reference a perfectly consistent field would render:
what the warp recovers when the reference is right, against which a run's figures read.

RUN is a run folder of ``va-train neus --data SCENE --set pipeline.model.view_warp.enabled=true`` (or a
``run_backbone.py`` row) whose scene is a GSO benchmark scene with the ``geometric`` or ``pose`` kind.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Dict, List

import numpy as np
import torch

from va_plugin.bench.recovery import recovery_main
from va_plugin.errors import VAError


def ideal_shifts(scene_dir: Path, info: Dict[str, Any]) -> Dict[int, np.ndarray]:
    """Rig view id -> the ideal shift ``[H, W, 2]`` (columns, rows; pixels) of each perturbed training view."""
    from va_plugin.data.scenes.inconsistency import InconsistencySpec, draw_perturbation, identity_map
    from va_plugin.data.scenes.rig import benchmark_cameras
    from va_plugin.data.scenes.sources import load_source

    if not str(info["source"]).startswith("gso:"):
        raise VAError(f"{scene_dir}: source {info['source']} is not a GSO object (only image sources are warped "
                      "in image space)")
    inc = info["inconsistency"]
    spec = InconsistencySpec(tuple(inc["kinds"]), int(inc["level"]), int(info["seed"]), tuple(inc["clean_views"]))
    resolution = int(info["resolution"])
    src = load_source(info["source"], resolution, Path(info["source_info"]["data_root"]))
    cameras = benchmark_cameras(resolution, extra=src.renderable)
    out = {}
    for view in info["train_views"]:
        if not spec.perturbs(view):
            continue
        coords = src.sampling_map(cameras, view, draw_perturbation(spec, view))
        if coords is not None:
            out[int(view)] = -(coords - identity_map(resolution, resolution))
    return out


def bilinear_basis(grid: int, height: int, width: int, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``[n, grid * grid]`` weights of the control points at pixels ``(rows, cols)``, as ``ViewWarp.shifts``."""
    gy = rows * ((grid - 1) / max(height - 1, 1))
    gx = cols * ((grid - 1) / max(width - 1, 1))
    r0 = np.clip(np.floor(gy).astype(int), 0, grid - 2)
    c0 = np.clip(np.floor(gx).astype(int), 0, grid - 2)
    fr, fc = gy - r0, gx - c0
    basis = np.zeros((len(rows), grid * grid))
    for dr, dc, weight in ((0, 0, (1 - fr) * (1 - fc)), (0, 1, (1 - fr) * fc), (1, 0, fr * (1 - fc)), (1, 1, fr * fc)):
        np.add.at(basis, (np.arange(len(rows)), (r0 + dr) * grid + c0 + dc), weight)
    return basis


def recovery(run_dir: Path) -> Dict[str, Any]:
    """Per perturbed training view of ``run_dir``: injected, learned-minus-ideal and floor RMS (pixels)."""
    from va_plugin.engine.trainer import load_checkpoint

    run_dir = Path(run_dir)
    if not (run_dir / "config.json").is_file():
        raise VAError(f"{run_dir}: no config.json; not a va-train run folder")
    state = load_checkpoint(run_dir, map_location="cpu")
    config = state["config_object"]
    warp_config = config.pipeline.model.view_warp
    if not warp_config.enabled or "view_warp.correction" not in state["model"]:
        raise VAError(f"{run_dir}: trained without pipeline.model.view_warp.enabled=true")
    warp = warp_config.setup(num_views=state["model"]["view_warp.correction"].shape[0])
    warp.load_state_dict({k[len("view_warp."):]: v for k, v in state["model"].items() if k.startswith("view_warp.")})
    scene_dir = Path(config.pipeline.datamanager.dataparser.data)
    if not (scene_dir / "scene.json").is_file():
        raise VAError(f"{run_dir} was trained on {scene_dir}, which has no scene.json here: not a benchmark scene")
    info = json.loads((scene_dir / "scene.json").read_text())
    ideal = ideal_shifts(scene_dir, info)

    def shifts_of(index, rows, cols, h, w):
        with torch.no_grad():
            return warp.shifts(torch.full((len(rows),), index), torch.from_numpy(rows), torch.from_numpy(cols),
                               h, w).double().numpy()

    return compare(str(run_dir), scene_dir, ideal, shifts_of, warp_config.grid, info["train_views"])


def compare(run: str, scene_dir: Path, ideal: Dict[int, np.ndarray], shifts_of, grid: int,
            views_in_order: List[int]) -> Dict[str, Any]:
    """The figures of learned shifts ``shifts_of(index, rows, cols, h, w) -> [n, 2]`` against ``ideal``."""
    from va_plugin.data.images import read_image

    views: List[Dict[str, Any]] = []
    for index, rig_id in enumerate(views_in_order):
        if int(rig_id) not in ideal:
            continue
        target = ideal[int(rig_id)]
        h, w = target.shape[:2]
        rgba = read_image(scene_dir / f"images/train_{int(rig_id):03d}.png")
        rows, cols = np.nonzero(rgba[:, :, 3] > 0.5)
        t = target[rows, cols].astype(np.float64)
        s = shifts_of(index, rows, cols, h, w)
        basis = bilinear_basis(grid, h, w, rows.astype(np.float64), cols.astype(np.float64))
        best = basis @ np.linalg.lstsq(basis, t, rcond=None)[0]
        rms = lambda x: float(np.sqrt((x ** 2).sum(-1).mean()))  # noqa: E731
        injected, left = rms(t), rms(s - t)
        views.append({"view": int(rig_id), "injected_px": round(injected, 3), "learned_px": round(rms(s), 3),
                      "left_px": round(left, 3), "floor_px": round(rms(best - t), 3),
                      "recovered": round(1.0 - left / max(injected, 1e-9), 3),
                      "along": round(float((s * t).sum() / max((t * t).sum(), 1e-12)), 3),
                      "along_x": round(float((s[:, 0] * t[:, 0]).sum() / max((t[:, 0] ** 2).sum(), 1e-12)), 3),
                      "along_y": round(float((s[:, 1] * t[:, 1]).sum() / max((t[:, 1] ** 2).sum(), 1e-12)), 3),
                      "injected_x_px": round(float(np.sqrt((t[:, 0] ** 2).mean())), 3),
                      "injected_y_px": round(float(np.sqrt((t[:, 1] ** 2).mean())), 3)})
    mean = lambda k: round(float(np.mean([v[k] for v in views])), 3) if views else None  # noqa: E731
    return {"run": run, "scene": scene_dir.name, "views": views,
            **{f"mean_{k}": mean(k) for k in ("injected_px", "learned_px", "left_px", "floor_px", "along", "along_x",
                                                  "along_y", "injected_x_px", "injected_y_px")}}


def register_against_clean(scene_dir: Path, grid: int = 5, steps: int = 300) -> Dict[str, Any]:
    """Each perturbed training view of a benchmark scene registered by a fresh warp against its clean render."""
    from va_plugin.data.images import read_image
    from va_plugin.model_components.view_warp import ViewWarpConfig, sample_bilinear

    scene_dir = Path(scene_dir)
    if not (scene_dir / "scene.json").is_file():
        raise VAError(f"{scene_dir}: no scene.json; not a benchmark scene folder")
    info = json.loads((scene_dir / "scene.json").read_text())
    ideal = ideal_shifts(scene_dir, info)
    learned: Dict[int, Any] = {}
    for index, rig_id in enumerate(info["train_views"]):
        if int(rig_id) not in ideal:
            continue
        warp = ViewWarpConfig(enabled=True, grid=grid, penalty_weight=0.0, frozen_views=()).setup(num_views=1)
        image = torch.from_numpy(read_image(scene_dir / f"images/train_{int(rig_id):03d}.png"))[None]
        clean = torch.from_numpy(read_image(scene_dir / f"images/clean_{int(rig_id):03d}.png"))
        h, w = clean.shape[:2]
        seen = ((clean[..., 3] > 0.05) | (image[0, ..., 3] > 0.05)).reshape(-1)
        rows, cols = (x.reshape(-1)[seen] for x in torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij"))
        views = torch.zeros_like(rows)
        target = clean.reshape(-1, clean.shape[-1])[seen]
        optimizer = torch.optim.Adam(warp.parameters(), lr=1e-3)
        for _ in range(steps):
            shift = warp.shifts(views, rows, cols, h, w)
            loss = ((sample_bilinear(image, views, rows + shift[:, 1], cols + shift[:, 0]) - target) ** 2).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        learned[index] = warp

    def shifts_of(index, rows, cols, h, w):
        with torch.no_grad():
            return learned[index].shifts(torch.zeros(len(rows), dtype=torch.long), torch.from_numpy(rows),
                                         torch.from_numpy(cols), h, w).double().numpy()

    return compare(f"{scene_dir} against its clean renders", scene_dir, ideal, shifts_of, grid, info["train_views"])


def show(r: Dict[str, Any]) -> None:
    print(f"{r['scene']}: injected {r['mean_injected_px']:.2f} px, learned {r['mean_learned_px']:.2f}, "
          f"left {r['mean_left_px']:.2f}, floor {r['mean_floor_px']:.2f}, along {r['mean_along']:+.2f} "
          f"(across the image {r['mean_along_x']:+.2f} of {r['mean_injected_x_px']:.2f} px, up it "
          f"{r['mean_along_y']:+.2f} of {r['mean_injected_y_px']:.2f} px) ({r['run']})")
    for v in r["views"]:
        print(f"  view {v['view']:2d}: injected {v['injected_px']:.2f}, learned {v['learned_px']:.2f}, left "
              f"{v['left_px']:.2f}, floor {v['floor_px']:.2f} px, recovered {v['recovered']:+.2f}, "
              f"along {v['along']:+.2f}")


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--against-clean" in argv:
        argv.remove("--against-clean")
        return recovery_main(__doc__.split("\n\n")[0], register_against_clean, show, argv)
    return recovery_main(__doc__.split("\n\n")[0], recovery, show, argv)


if __name__ == "__main__":
    sys.exit(main())
