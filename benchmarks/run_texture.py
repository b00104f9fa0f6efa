"""Textured meshes against field renders on held-out views (issue 20).

For each run folder: extract the mesh (marching cubes, 128^3), bake a texture from the training views with
robust fusion (per-view color harmonisation, then a consensus) and with plain angle-weighted averaging
(``--bakes`` adds robust fusion without the harmonisation and the average with it), render both by ray
casting at every held-out view, and score them with the field's own renders (PSNR, SSIM, LPIPS). The
textured renders take one ray through each pixel centre, as the field's do (``--supersample 2``: 2x2 rays
a pixel, the setting before 2026-11-28). Also times the bake from 16 views (the 4 inputs plus 12 held-out
views as stand-ins) on the same mesh. One JSON line per run in --out; a table of all lines at the end.

    OMP_NUM_THREADS=1 python benchmarks/run_texture.py --runs outputs/texture20/runs/*_l2 \\
        --out outputs/texture20/l2.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from va_plugin.api import load_run
from va_plugin.bench.store import ROWS_FILE, ResultStore, append_row, keyed_rows
from va_plugin.cli.common import friendly_errors
from va_plugin.errors import ConfigError
from va_plugin.eval.evaluate import ground_truth_mesh_path, image_metrics, load_mesh
from va_plugin.eval.mesh_render import SCORE_SUPERSAMPLE, check_supersample, textured_mesh_metrics
from va_plugin.export.atlas import MAX_TEXTURE_FACES
from va_plugin.export.mesh import extract_mesh
from va_plugin.export.texture import bake_texture, check_texture_size, run_views
from va_plugin.export.views import Views
from va_plugin.export.writing import bake_picture

KEYS = ("psnr", "ssim", "lpips")
BAKES = {"robust": dict(fusion="robust"),  # with the per-view color harmonisation (the default)
         "mean": dict(fusion="mean"),  # the plain angle-weighted average
         "robust-plain": dict(fusion="robust", harmonise_views=False),
         "mean-harmonised": dict(fusion="mean", harmonise_views=True)}


def bake_options(name: str) -> dict:
    """bake_texture's options of a ``--bakes`` entry (ConfigError for an unknown one)."""
    if name in BAKES:
        return BAKES[name]
    raise ConfigError(f"--bakes: unknown {name!r}; known: {', '.join(BAKES)}")


def timing_views(pipeline, count: int) -> Views:
    """``count`` views of 256 px: the run's inputs, then held-out views."""
    dm = pipeline.datamanager
    train, test = run_views(pipeline), dm.test
    extra = count - len(train)
    if extra <= 0 or test is None or len(test) < extra:
        raise ConfigError(f"the run has too few views for a {count}-view timing")
    cameras = type(train.cameras)(torch.cat([train.cameras.c2w, test.cameras.c2w[:extra]]),
                                  torch.cat([train.cameras.fx, test.cameras.fx[:extra]]),
                                  torch.cat([train.cameras.fy, test.cameras.fy[:extra]]),
                                  torch.cat([train.cameras.cx, test.cameras.cx[:extra]]),
                                  torch.cat([train.cameras.cy, test.cameras.cy[:extra]]),
                                  train.cameras.width, train.cameras.height, train.cameras.camera_type,
                                  train.cameras.pixel_offset)
    images = np.concatenate([train.images, test.images[:extra].numpy()])
    return Views(cameras, images.astype(np.float32))


def benchmark_row(run: Path):
    """The benchmark row that scored ``run``: ``RUN/bench_row.json`` when it holds the scores, else the line of
    the results folder's ``rows.jsonl`` (run_backbone / run_table1 write it in a folder above the run) whose
    ``run_dir`` is this run; None when neither does."""
    marker = run / "bench_row.json"
    if marker.is_file():
        row = json.loads(marker.read_text())
        if all(k in row for k in KEYS):
            return row, marker
    here = run.resolve()
    for folder in list(here.parents)[:5]:
        if (folder / ROWS_FILE).is_file():
            for row in ResultStore(folder, resume=True).rows.values():
                if row.get("run_dir") and Path(row["run_dir"]).resolve() == here and all(k in row for k in KEYS):
                    return row, folder / ROWS_FILE
    return None


def field_scores(pipeline, run: Path, max_views, reuse: bool) -> dict:
    """The field's held-out scores: from the benchmark row that scored every held-out view of the run
    (:func:`benchmark_row`) when ``reuse`` and every view is asked for, else rendered here."""
    found = benchmark_row(run) if reuse and max_views is None else None
    if found is not None:
        row, source = found
        views = row.get("evaluation", {}).get("image_params", {}).get("views")
        if views is not None:
            return {**{k: row[k] for k in KEYS}, "image_params": {"views": views}, "from": str(source)}
    if reuse and max_views is None:
        print(f"{run}: no benchmark row with its scores found; rendering the field's held-out views", flush=True)
    return image_metrics(pipeline, max_views=max_views, progress=False)


def run_mesh(pipeline, source: str, resolution: int):
    """The mesh to texture: the run's own (marching cubes at ``resolution``^3) or, as a diagnostic of how much
    of the textured score is the geometry's, the scene's ground-truth mesh."""
    if source == "truth":
        path = ground_truth_mesh_path(pipeline)
        if path is None:
            raise ConfigError("--mesh truth: the run's scene has no ground-truth mesh")
        return load_mesh(path)
    return extract_mesh(pipeline.model, resolution=resolution, with_color=False)


def evaluate(run: Path, size: int, max_views, timing_count: int, bakes=("robust", "mean"),
             reuse_field: bool = False, mesh_source: str = "extracted", mesh_resolution: int = 128,
             max_faces: int = MAX_TEXTURE_FACES, supersample: int = SCORE_SUPERSAMPLE) -> dict:
    pipeline, state = load_run(run, device="cpu").parts()
    record = {"run": str(run), "steps": int(state["step"]), "mesh": mesh_source, "texture_size": size,
              "max_faces": max_faces, "supersample": supersample}
    if mesh_source == "extracted":
        record["mesh_resolution"] = mesh_resolution
    started = time.perf_counter()
    mesh = run_mesh(pipeline, mesh_source, mesh_resolution)
    record["mesh_seconds"] = round(time.perf_counter() - started, 2)
    record["vertices"], record["faces"] = len(mesh.vertices), len(mesh.faces)
    field = field_scores(pipeline, run, max_views, reuse_field)
    record["field"] = {k: field[k] for k in KEYS}
    if "from" in field:
        record["field_from"] = field["from"]
    record["views"] = field["image_params"]["views"]
    atlas = None
    for fusion in bakes:
        textured, report = bake_texture(mesh, run_views(pipeline), size=size, atlas=atlas,
                                        max_faces=max_faces, **bake_options(fusion))
        record["faces_textured"] = len(textured.faces)
        atlas = (textured.vertices, textured.faces, textured.uv)  # unwrap once, bake twice
        scores = textured_mesh_metrics(pipeline, textured, max_views=max_views, progress=False,
                                       supersample=supersample)
        record[fusion] = {**{k: scores[k] for k in KEYS}, **report.summary()}
        if fusion == "robust" and mesh_source == "extracted" and mesh_resolution == 128:
            bake_picture(textured, report, run / "texture_bake.png")
    if timing_count:
        _, report = bake_texture(mesh, timing_views(pipeline, timing_count), size=size, fusion="robust",
                                 atlas=atlas)
        record[f"bake_{timing_count}_views_seconds"] = report.summary()["seconds"]
    return record


def resume_key(record: dict) -> tuple:
    """What makes two records the same measurement: the run, the mesh (source and grid), the texture size, the
    face cap and the rays a pixel of the textured renders. Records written before these were kept are read
    as the defaults of then (extracted, 128, 1024, no cap, 2x2 rays)."""
    mesh = record.get("mesh", "extracted")
    resolution = record.get("mesh_resolution", 128) if mesh == "extracted" else None
    return (record["run"], mesh, resolution, record.get("texture_size", 1024), record.get("max_faces", 0),
            record.get("supersample", 2))


def table(records) -> str:
    rows = ["| run | field PSNR / SSIM / LPIPS | mesh robust | mesh mean | robust better than field (LPIPS) |",
            "|---|---|---|---|---|"]
    for r in records:
        cells = [" / ".join(f"{r[part][k]:.4f}" if k != "psnr" else f"{r[part][k]:.2f}" for k in KEYS)
                 for part in ("field", "robust", "mean")]
        rows.append(f"| {Path(r['run']).name} | {' | '.join(cells)} | "
                    f"{'yes' if r['robust']['lpips'] < r['field']['lpips'] else 'no'} |")
    lp = {part: [r[part]["lpips"] for r in records] for part in ("field", "robust", "mean")}
    rows.append(f"| median | {np.median(lp['field']):.4f} | {np.median(lp['robust']):.4f} | "
                f"{np.median(lp['mean']):.4f} | {sum(a < b for a, b in zip(lp['robust'], lp['field']))}/"
                f"{len(records)} |")
    return "\n".join(rows)


@friendly_errors
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, nargs="+", required=True, help="run folders of va-train")
    parser.add_argument("--out", type=Path, required=True,
                        help="JSON lines, one per run and setting (appended; a run already scored with the same "
                        "--mesh, --mesh-resolution and --texture-size is skipped)")
    parser.add_argument("--texture-size", type=int, default=1024)
    parser.add_argument("--max-views", type=int, default=None, help="score at most this many held-out views")
    parser.add_argument("--timing-views", type=int, default=16,
                        help="on the first run, also time a bake from this many views (0: no)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--bakes", default="robust,mean",
                        help=f"comma-separated bakes to score, from {', '.join(BAKES)}; robust and mean always")
    parser.add_argument("--reuse-field-scores", action="store_true",
                        help="take the field's scores from the benchmark row of the run (all held-out views: "
                        "RUN/bench_row.json or the rows.jsonl of the results folder above it, written by "
                        "run_backbone) instead of rendering them again; needs no --max-views")
    parser.add_argument("--mesh", choices=("extracted", "truth"), default="extracted",
                        help="texture the run's own mesh (default) or the scene's ground-truth mesh: how much of "
                        "the textured score is the geometry's")
    parser.add_argument("--mesh-resolution", type=int, default=128,
                        help="marching-cubes grid of the extracted mesh (default 128)")
    parser.add_argument("--max-faces", type=int, default=MAX_TEXTURE_FACES,
                        help=f"simplify the mesh to at most this many faces before the unwrap (default "
                        f"{MAX_TEXTURE_FACES}, as va-export; 0 keeps every face)")
    parser.add_argument("--supersample", type=int, default=SCORE_SUPERSAMPLE,
                        help=f"rays per pixel side for the textured meshes' renders (default {SCORE_SUPERSAMPLE}: "
                        "one through each pixel centre, as the field's renders; 2 averages 2x2 rays, as before "
                        "2026-11-28)")
    args = parser.parse_args(argv)
    check_supersample(args.supersample, "--supersample")
    if args.max_faces < 0 or 0 < args.max_faces < 4:
        raise ConfigError(f"--max-faces must be 0 (keep every face) or at least 4, got {args.max_faces}")
    if not 16 <= args.mesh_resolution <= 512:
        raise ConfigError(f"--mesh-resolution must be in [16, 512], got {args.mesh_resolution}")
    bakes = [b.strip() for b in args.bakes.split(",") if b.strip()]
    for b in bakes:
        bake_options(b)
    bakes = ["robust", "mean"] + [b for b in bakes if b not in ("robust", "mean")]
    check_texture_size(args.texture_size)
    torch.set_num_threads(args.threads)
    done = keyed_rows(args.out, resume_key)
    key = lambda run: resume_key({"run": str(run), "mesh": args.mesh, "mesh_resolution": args.mesh_resolution,
                                  "texture_size": args.texture_size, "max_faces": args.max_faces,
                                  "supersample": args.supersample})
    for k, run in enumerate(args.runs):
        if key(run) in done:
            continue
        record = evaluate(run, args.texture_size, args.max_views, args.timing_views if k == 0 else 0, bakes,
                          args.reuse_field_scores, args.mesh, args.mesh_resolution, args.max_faces, args.supersample)
        done[key(run)] = record
        append_row(args.out, record)
        print(f"{run.name}: field lpips {record['field']['lpips']:.4f}, mesh robust {record['robust']['lpips']:.4f}, "
              f"mean {record['mean']['lpips']:.4f}; bake {record['robust']['seconds']}", flush=True)
    print(table([done[key(r)] for r in args.runs if key(r) in done]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
