"""Do the meshes written for 3D tools stand upright on real generator outputs? And does ``--faces`` hold?

    python benchmarks/upright_check.py [--data-root ../shared/data/generated] [--out outputs/upright]
        [--quality fast] [--steps N] [--faces 20000] [--texture-size 512] [--threads 1] [--inputs fox,lamp]

Each input of ``--data-root`` (the SyncDreamer strips and Zero123++ grids) is reconstructed as
``va-recon INPUT --quality fast --faces 20000 --turntable-frames 0`` would (a short training: what is
checked is the files' frame, not the shape's quality; a finished run folder is continued, not retrained),
then its ``mesh.glb`` and ``mesh.obj`` are loaded back with trimesh and checked:

- lowest vertex at y = 0 and the bounding box centred on the y axis (x and z);
- up is +Y: the training cameras, taken into the file's frame by ``mesh_frame.json``, sit above the
  object's mid-height (every rig looks down on the object on average), and the input view's side faces
  +Z (the azimuth of view 0 about +Y, from +Z: SyncDreamer's view 0 is the input view, 0 deg; Zero123++'s
  first view is 30 deg from it);
- the face count against ``--faces`` (within 1%);
- ``mesh.ply`` is still the training frame: the textured mesh's vertices, taken back by
  ``file_to_training``, lie on the PLY's surface (distance in marching-cubes cells).

Writes ``OUT/upright.json`` and ``OUT/upright.md`` (one row per input); exit 1 when a check fails.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np
import trimesh

from va_plugin.bench.catalog import DEFAULT_GENERATED_ROOT, generator_outputs
from va_plugin.cli.common import friendly_errors

REPO = Path(__file__).resolve().parents[1]
FACES_TOLERANCE = 0.01


def transform(points: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    return np.asarray(points, np.float64) @ matrix[:3, :3].T + matrix[:3, 3]


def check_file(path: Path, frame: dict, cameras: np.ndarray, faces: int, ply: trimesh.Trimesh,
               cell: float) -> dict:
    """The checks of one GLB or OBJ file (see the module docstring)."""
    from va_plugin.raycast import o3d

    mesh = trimesh.load(path, force="mesh", process=False)
    low, high = mesh.bounds
    to_file, to_training = np.array(frame["training_to_file"]), np.array(frame["file_to_training"])
    eyes = transform(cameras, to_file)
    azimuth = math.degrees(math.atan2(eyes[0, 0], eyes[0, 2]))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(ply.vertices, np.float32)),
                        o3d.core.Tensor(np.asarray(ply.faces, np.uint32)))
    back = transform(mesh.vertices, to_training).astype(np.float32)
    off = scene.compute_distance(o3d.core.Tensor(back)).numpy()
    return {"faces": len(mesh.faces), "faces_error": round(abs(len(mesh.faces) - faces) / faces, 5),
            "min_y": float(low[1]), "centre_x": float((low[0] + high[0]) / 2),
            "centre_z": float((low[2] + high[2]) / 2),
            "extent_xyz": [round(float(v), 4) for v in high - low],
            "camera_height_over_mid": round(float(eyes[:, 1].mean() - (low[1] + high[1]) / 2), 4),
            "view0_azimuth_deg": round(azimuth, 1),
            "off_ply_cells_max": round(float(off.max() / cell), 3),
            "volume_positive": bool(mesh.volume > 0) if mesh.is_watertight else None}


def passed(row: dict, faces: int) -> bool:
    return (abs(row["min_y"]) < 1e-6 and abs(row["centre_x"]) < 1e-6 and abs(row["centre_z"]) < 1e-6
            and row["camera_height_over_mid"] > 0 and row["faces_error"] <= FACES_TOLERANCE
            and row["off_ply_cells_max"] < 1.0 and row["extent_xyz"][1] > 0)


def run_input(name: str, source: Path, args) -> dict:
    """Reconstruct one input (output to ``RUN.log``) and check its files."""
    from va_plugin.api import load_run, reconstruct

    run_dir = args.out / "runs" / name
    run_dir.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    with open(args.out / "runs" / f"{name}.log", "a") as log, redirect_stdout(log), redirect_stderr(log):
        result = reconstruct(source, run_dir, quality=args.quality, steps=args.steps, device="cpu",
                             texture_size=args.texture_size, turntable_frames=0, faces=args.faces,
                             threads=args.threads, resume=True)
    seconds = time.perf_counter() - started
    loaded = load_run(run_dir, device="cpu")
    cameras = loaded.pipeline.datamanager.cameras.centers.cpu().numpy()
    ply = trimesh.load(run_dir / "mesh.ply", process=False)
    radius = float(loaded.pipeline.model.scene.scene_radius)
    cell = 2.0 * radius / (128 - 1)
    frame = json.loads((run_dir / "mesh_frame.json").read_text())
    row = {"input": name, "seconds": round(seconds, 1), "steps": result.steps, "faces_extracted": len(ply.faces),
           "ply_extent_xyz": [round(float(v), 4) for v in ply.extents],
           "ply_max_radius": round(float(np.linalg.norm(ply.vertices, axis=1).max()), 4), "scene_radius": radius}
    for suffix in ("glb", "obj"):
        row[suffix] = check_file(run_dir / f"mesh.{suffix}", frame, cameras, args.faces, ply, cell)
        row[suffix]["ok"] = passed(row[suffix], args.faces)
    return row


def markdown(rows: list[dict], faces: int) -> str:
    lines = [f"| input | steps | PLY extent x, y, z (training, z up) | GLB extent x, y, z (y up) | GLB / OBJ min y "
             f"| centre x, z | cameras above mid-height | view 0 azimuth from +Z | faces GLB / OBJ (--faces {faces}) "
             "| off mesh.ply (cells) | ok |", "|" + "---|" * 11]
    for r in rows:
        g, o = r["glb"], r["obj"]
        lines.append(
            f"| {r['input']} | {r['steps']} | {', '.join(f'{v:.3f}' for v in r['ply_extent_xyz'])} "
            f"| {', '.join(f'{v:.3f}' for v in g['extent_xyz'])} | {g['min_y']:.1e} / {o['min_y']:.1e} "
            f"| {max(abs(g['centre_x']), abs(o['centre_x'])):.0e}, {max(abs(g['centre_z']), abs(o['centre_z'])):.0e} "
            f"| +{g['camera_height_over_mid']:.3f} | {g['view0_azimuth_deg']:.1f} deg "
            f"| {g['faces']} / {o['faces']} | {max(g['off_ply_cells_max'], o['off_ply_cells_max']):.3f} "
            f"| {'yes' if g['ok'] and o['ok'] else 'NO'} |")
    return "\n".join(lines) + "\n"


@friendly_errors
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-root", type=Path, default=DEFAULT_GENERATED_ROOT)
    parser.add_argument("--out", type=Path, default=REPO / "outputs" / "upright")
    parser.add_argument("--quality", default="fast", choices=("fast", "default", "accurate"))
    parser.add_argument("--steps", type=int, default=None, help="training steps (default: the quality's)")
    parser.add_argument("--faces", type=int, default=20000)
    parser.add_argument("--texture-size", type=int, default=512)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--inputs", default="", help="comma-separated input names (default: all)")
    args = parser.parse_args(argv)
    inputs = generator_outputs(args.data_root, folders=False)
    if args.inputs:
        inputs = [(n, p) for n, p in inputs if n in args.inputs.split(",")]
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name, source in inputs:
        rows.append(run_input(name, source, args))
        print(f"{name}: {'ok' if rows[-1]['glb']['ok'] and rows[-1]['obj']['ok'] else 'FAILED'} "
              f"({rows[-1]['seconds']:.0f} s)", file=sys.stderr, flush=True)
        (args.out / "upright.json").write_text(json.dumps(rows, indent=2))
    (args.out / "upright.md").write_text(markdown(rows, args.faces))
    print(markdown(rows, args.faces))
    return 0 if all(r["glb"]["ok"] and r["obj"]["ok"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
