"""How much of a benchmark scene's injected pose error a run's camera refinement recovered.

A benchmark scene's ``pose`` inconsistency renders view i from a slightly wrong orbit position (azimuth,
elevation, roll errors in its ``scene.json``) and writes the nominal camera. Both cameras look at the
origin from the same distance, so the exact correction is one rotation about the world origin,
``R_true = R_perturbed R_nominal^T`` (camera-to-world rotations): what ``camera_opt.mode=SO3`` learns.
For each run and training view this prints the injected angle, the learned angle, and the angle left
between them (``|log(R_learned^T R_true)|``); "recovered" is ``1 - left / injected`` (1: exact, 0: no
better than no correction, below 0: worse than none).

    python benchmarks/bench_camera_recovery.py RUN [RUN ...] [--json OUT.json]

RUN is a run folder of ``va-train neus --data SCENE --set pipeline.model.camera_opt.mode=SO3`` (or a
``run_backbone.py`` row) whose scene is a benchmark scene with the ``pose`` kind.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any, Dict, List

import torch

from va_plugin.bench.recovery import recovery_main
from va_plugin.errors import VAError


def rotation_angle_deg(rotation: torch.Tensor) -> float:
    """The angle of a rotation matrix ``[3, 3]`` in degrees: atan2 of its sine (half the length of the
    antisymmetric part's axis vector) and cosine ((trace - 1) / 2); acos alone loses small angles to
    rounding (float32 cameras: 0.01 deg)."""
    skew = rotation - rotation.T
    sine = 0.5 * float(torch.stack([skew[2, 1], skew[0, 2], skew[1, 0]]).norm())
    cosine = 0.5 * (float(torch.trace(rotation)) - 1.0)
    return math.degrees(math.atan2(sine, cosine))


def true_corrections(scene_dir: Path) -> Dict[int, torch.Tensor]:
    """Rig view id -> the rotation ``[3, 3]`` that takes its nominal camera to the one it was rendered
    from (identity for views without a pose error)."""
    from va_plugin.data.scenes.rig import benchmark_cameras
    from va_plugin.data.scenes.sources import perturbed_camera

    info = json.loads((Path(scene_dir) / "scene.json").read_text())
    cameras = benchmark_cameras(int(info["resolution"]))
    out = {}
    for view in info["inconsistency"]["per_view"]:
        rig_id = int(view["view"])
        nominal = cameras.c2w[rig_id, :, :3].double()
        error = view.get("pose_error_deg")
        if error is None:
            out[rig_id] = torch.eye(3, dtype=torch.float64)
            continue
        moved = perturbed_camera(cameras, rig_id, (error["azimuth"], error["elevation"], error["roll"]))
        out[rig_id] = moved.c2w[0, :, :3].double() @ nominal.T
    return out


def recovery(run_dir: Path) -> Dict[str, Any]:
    """Per training view of ``run_dir``: injected, learned and left-over angles (degrees)."""
    from va_plugin.model_components.camera_opt import rotation_matrix
    from va_plugin.models.neus import CAMERA_REFINEMENT_FILE

    run_dir = Path(run_dir)
    refinement_file = run_dir / CAMERA_REFINEMENT_FILE
    if not refinement_file.is_file():
        raise VAError(f"{run_dir}: no {CAMERA_REFINEMENT_FILE} (was the run trained to its end with "
                      "pipeline.model.camera_opt.mode=SO3 or SE3?)")
    learned = json.loads(refinement_file.read_text())
    if "rotation_vector" not in learned:
        raise VAError(f"{refinement_file}: written by an older version without rotation vectors; retrain")
    if not (run_dir / "config.json").is_file():
        raise VAError(f"{run_dir}: no config.json; not a va-train run folder")
    config = json.loads((run_dir / "config.json").read_text())
    scene_dir = Path(config["pipeline"]["datamanager"]["dataparser"]["data"])
    if not (scene_dir / "scene.json").is_file():
        raise VAError(f"{run_dir} was trained on {scene_dir}, which has no scene.json here: not a benchmark "
                      "scene, or a relative path to be read from the folder the run was trained in")
    info = json.loads((scene_dir / "scene.json").read_text())
    truth = true_corrections(scene_dir)
    views: List[Dict[str, Any]] = []
    for index, rig_id in enumerate(info["train_views"]):
        true_rotation = truth[int(rig_id)]
        estimate = rotation_matrix(torch.tensor(learned["rotation_vector"][index], dtype=torch.float64))
        injected = rotation_angle_deg(true_rotation)
        left = rotation_angle_deg(estimate.T @ true_rotation)
        views.append({"view": int(rig_id), "injected_deg": round(injected, 3),
                      "learned_deg": round(rotation_angle_deg(estimate), 3), "left_deg": round(left, 3),
                      "recovered": round(1.0 - left / injected, 3) if injected > 1e-6 else None})
    perturbed = [v for v in views if v["recovered"] is not None]
    return {"run": str(run_dir), "scene": scene_dir.name, "views": views,
            "mean_injected_deg": round(sum(v["injected_deg"] for v in perturbed) / max(len(perturbed), 1), 3),
            "mean_left_deg": round(sum(v["left_deg"] for v in perturbed) / max(len(perturbed), 1), 3)}


def show(result: Dict[str, Any]) -> None:
    print(f"{result['scene']}: injected {result['mean_injected_deg']:.2f} deg on the mean, "
          f"left {result['mean_left_deg']:.2f} deg ({result['run']})")
    for v in result["views"]:
        share = "-" if v["recovered"] is None else f"{v['recovered']:+.2f}"
        print(f"  view {v['view']:2d}: injected {v['injected_deg']:.2f}, learned {v['learned_deg']:.2f}, "
              f"left {v['left_deg']:.2f} deg, recovered {share}")


def main(argv=None) -> int:
    return recovery_main(__doc__.split("\n\n")[0], recovery, show, argv)


if __name__ == "__main__":
    sys.exit(main())
