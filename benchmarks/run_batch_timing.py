"""va-batch's engines timed on the same 8 tiny objects, in one run:

    python benchmarks/run_batch_timing.py [--out outputs/batch_timing] [--resolution 32] [--steps 40]
        [--skip-ray]

The 8 objects are the 7 procedural objects at level 0 and the mug at level 2 (4 views, ``--resolution`` px,
with ground truth). The same ``va-batch`` command (``--steps``, 256 rays a step, a 64^3 mesh, a 128^2
texture, evaluation on 4 held-out views and with 20k surface samples) runs three times, one after the other:

1. ``sequential``: ``--workers 1 --threads 2`` (the objects one after another, two torch threads each);
2. ``local``: ``--workers 2`` (two worker processes, one thread each; the default on 2 cores);
3. ``ray``: ``--engine ray --workers 2`` (a local Ray instance started by the command, 1 CPU a task).

Wall time is the whole command's (start-up, scene reading, training, meshes, textures, evaluation, reports).
Per-object results of ``local`` and ``ray`` are compared (name, status, cd, iou, fscore, psnr, ssim,
lpips, steps must be identical: training is seeded and both run one thread a job). Writes
``OUT/timing.json`` and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
OBJECTS = [("mug", 0), ("knot", 0), ("chair", 0), ("bowl", 0), ("blocks", 0), ("lamp", 0), ("robot", 0), ("mug", 2)]
COMPARED = ("name", "status", "cd", "iou", "fscore", "psnr", "ssim", "lpips", "steps", "error")
ENGINES = {"sequential": ["--workers", "1", "--threads", "2"], "local": ["--workers", "2"],
           "ray": ["--engine", "ray", "--workers", "2"]}


def build_inputs(folder: Path, resolution: int) -> Path:
    from va_plugin.data.scenes.builder import build_procedural_scene

    for name, level in OBJECTS:
        scene = folder / f"{name}_l{level}"
        if not (scene / "scene.json").is_file():
            build_procedural_scene(scene, name, n_views=4, resolution=resolution, mesh_resolution=96, level=level)
    return folder


def rows(out: Path):
    with open(out / "summary.csv", newline="") as handle:
        return {r["name"]: r for r in csv.DictReader(handle)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO / "outputs" / "batch_timing")
    parser.add_argument("--resolution", type=int, default=32)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--skip-ray", action="store_true")
    args = parser.parse_args()
    inputs = build_inputs(args.out / "inputs", args.resolution)
    common = ["--method", "neus", "--steps", str(args.steps), "--device", "cpu", "--no-progress",
              "--set", "pipeline.datamanager.rays_per_batch=256", "--mesh-resolution", "64",
              "--eval-samples", "20000", "--eval-max-views", "4", "--texture-size", "128"]
    result = {"date": time.strftime("%Y-%m-%d"), "cpus": os.cpu_count(), "objects": len(OBJECTS),
              "resolution": args.resolution, "steps": args.steps, "runs": {}}
    for engine, flags in ENGINES.items():
        if engine == "ray" and args.skip_ray:
            continue
        out = args.out / engine
        command = [str(REPO / ".venv" / "bin" / "va-batch"), str(inputs), "--out", str(out), *common, *flags]
        subprocess.run(["rm", "-rf", str(out)], check=True)
        load = os.getloadavg()[0]
        started = time.perf_counter()
        code = subprocess.run(command, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode
        wall = time.perf_counter() - started
        per_object = rows(out)
        result["runs"][engine] = {
            "command": " ".join(["va-batch", *command[1:]]).replace(str(REPO) + "/", ""), "exit": code,
            "wall_seconds": round(wall, 1), "load_average_before": round(load, 2),
            "mean_object_seconds": round(sum(float(r["seconds"]) for r in per_object.values()) / len(per_object), 2),
            "failed": sum(r["status"] != "ok" for r in per_object.values())}
        print(f"{engine}: {wall:.1f} s (exit {code}, load {load:.2f} before)", flush=True)
    runs = result["runs"]
    base = runs["sequential"]["wall_seconds"]
    for engine, run in runs.items():
        run["ratio_to_sequential"] = round(run["wall_seconds"] / base, 3)
    if "ray" in runs:
        runs["ray"]["ratio_to_local"] = round(runs["ray"]["wall_seconds"] / runs["local"]["wall_seconds"], 3)
        local, ray = rows(args.out / "local"), rows(args.out / "ray")
        result["ray_identical_to_local"] = all({k: local[n][k] for k in COMPARED} == {k: ray[n][k] for k in COMPARED}
                                               for n in local) and set(local) == set(ray)
    seq, local = rows(args.out / "sequential"), rows(args.out / "local")
    result["sequential_identical_to_local"] = all(
        {k: seq[n][k] for k in COMPARED} == {k: local[n][k] for k in COMPARED} for n in local)
    (args.out / "timing.json").write_text(json.dumps(result, indent=2))
    print("| engine | wall s | / sequential | mean object s | failed |\n|---|---|---|---|---|")
    for engine, run in runs.items():
        print(f"| {engine} | {run['wall_seconds']} | {run['ratio_to_sequential']} | {run['mean_object_seconds']} | "
              f"{run['failed']} |")
    print(json.dumps({k: v for k, v in result.items() if k != "runs"}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
