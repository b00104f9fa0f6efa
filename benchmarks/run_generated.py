"""Real generator outputs, end to end: every file of ``../shared/data/generated`` with ``neus`` and ``va-neus``.

    python benchmarks/run_generated.py [--data-root ../shared/data/generated] [--out outputs/generated]
        [--methods neus,va-neus] [--inputs aircraft_0,fox] [--steps N] [--threads 2] [--resume]

Each run is the user's command, ``va-train METHOD --data FILE --export-mesh``, with default options,
trained in this process by ``train_run`` as va-train trains it (format detected, the generator's documented rig).
There is no ground truth for generated views, so what
is recorded is the run time, the last training batch's PSNR (against the generator's own views), the
PSNR of the shared path (the novel-view render the mesh comes from) at the training views against the
inputs (half size, cached in ``RUN/train_views_psnr.json``), the rig check (silhouette IoU of the masks' visual
hull) and, for ``va-neus``, whether the consistency test
ran the adaptive phases and the mean inconsistency per view. Writes into OUT:

- ``runs/<input>-<method>/``: the run folders (mesh.ply, masks.png, inconsistency.png, attention.png);
- ``generated.json`` / ``generated.md``: one row per (input, method);
- ``generated_meshes.png``: a row per input: its first view, then three grey turntable frames of each
  method's mesh (SyncDreamer orbit, 30 deg elevation);
- ``<input>-<method>_inconsistency.png``: a copy of each view-adaptive run's inconsistency maps;
- ``generated_inconsistency.png``: a row per view-adaptive run that ran its adaptive phases: each
  training view's input beside its inconsistency map.

``--resume`` skips (input, method) pairs whose run folder already has its mesh; an interrupted run is
continued from its newest checkpoint.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

from va_plugin.analysis.consistency import residual_spread_db
from va_plugin.bench.catalog import DEFAULT_GENERATED_ROOT, generator_outputs
from va_plugin.bench.store import ROWS_FILE, append_row, keyed_rows
from va_plugin.cli.common import friendly_errors
from va_plugin.engine.metrics_log import read_records

REPO = Path(__file__).resolve().parents[1]


def last_metrics(run_dir: Path) -> dict:
    """The last logged training step and the adaptive-phase events of a run's metrics.jsonl."""
    out = {}
    for row in read_records(run_dir):
        if "psnr" in row and "event" not in row:
            out["train_psnr"] = row["psnr"]
            out["steps"] = row.get("step")
        if "skipped_adaptive" in row:
            out["adaptive_phases"] = "skipped (inputs look consistent)"
        if "residual_spread_db" in row:
            out["adaptive_phases"] = "ran"
            out["residual_spread_db"] = row["residual_spread_db"]
    return out


def inconsistency_summary(run_dir: Path):
    """Mean |branch render - canonical render| per view, from the run's inconsistency.json (or None)."""
    path = run_dir / "inconsistency.json"
    if not path.is_file():
        return None
    data = json.loads(path.read_text())
    return [float(f"{float(v['mean_abs_difference']):.3g}") for v in data.get("views", [])]


def run_one(method: str, source: Path, run_dir: Path, args) -> float:
    """Train (or resume) one run as ``va-train METHOD --data SOURCE --export-mesh`` would, in this process
    (output to ``RUN.log`` beside the run folder); returns its wall seconds."""
    from va_plugin.api import build_config, export_mesh, train

    overrides = [f"num_threads={args.threads}"]
    if args.force_adaptive and method.startswith("va-"):
        overrides.append("pipeline.model.field.skip_consistent_scenes=false")
    config = build_config(method, source, out=run_dir, steps=args.steps or None, progress=False,
                          overrides=[*overrides, *args.set])
    start = time.perf_counter()
    run_dir.mkdir(parents=True, exist_ok=True)
    with open(run_dir.parent / f"{run_dir.name}.log", "w") as log, redirect_stdout(log), redirect_stderr(log):
        train(config, resume=args.resume)
        export_mesh(run_dir, texture=False, device="cpu")
    return time.perf_counter() - start


def shared_path_psnr(run_dir: Path, scale: float = 0.5):
    """Mean PSNR of the run's shared (novel-view) path rendered at its training views against the inputs,
    at ``scale`` of their size (area-resized targets): for ``va-neus`` the object the mesh comes from, not
    a branch. Cached in ``RUN/train_views_psnr.json``; None when the run has no checkpoint."""
    import cv2
    import torch

    from va_plugin.api import load_run
    from va_plugin.engine.trainer import list_checkpoints
    from va_plugin.eval.image import psnr
    from va_plugin.export.render import render_view

    cache = run_dir / "train_views_psnr.json"
    if cache.is_file():
        return json.loads(cache.read_text())["mean_psnr"]
    if not list_checkpoints(run_dir):
        return None
    pipeline, _ = load_run(run_dir, device="cpu").parts()
    datamanager = pipeline.datamanager
    cameras = datamanager.cameras.scaled(scale)
    values = []
    with torch.no_grad():
        for view in range(datamanager.num_train_views):
            render = render_view(pipeline.model, cameras, view)
            target = cv2.resize(datamanager.images[view].cpu().numpy(), (cameras.width, cameras.height),
                                interpolation=cv2.INTER_AREA)
            values.append(psnr(render, target))
    mean = round(sum(values) / len(values), 2)
    cache.write_text(json.dumps({"scale": scale, "per_view_psnr": [round(v, 2) for v in values], "mean_psnr": mean}))
    return mean


def rig_check(source: Path) -> dict:
    """The dataparser's own rig check for one input: per-view silhouette IoU of the masks' visual hull."""
    from va_plugin.data.dataparsers import resolve_dataparser

    outputs = resolve_dataparser(source).setup().get_outputs("train")
    ious = outputs.metadata.get("silhouette_iou")
    if not ious:
        return {}
    return {"silhouette_iou_mean": round(sum(ious) / len(ious), 3), "silhouette_iou_min": round(min(ious), 3)}


def summary_figure(inputs, methods, out: Path, frames: int = 3, resolution: int = 128):
    """One row per input: its first training view, then ``frames`` grey turntable frames of the mesh of
    each run name in ``methods`` (``RUNS/INPUT-NAME``; SyncDreamer orbit, 30 deg elevation), white where
    that run has no mesh; inputs with no mesh at all are left out. Written to ``OUT/generated_meshes.png``."""
    import cv2
    import numpy as np

    from va_plugin.data.dataparsers import resolve_dataparser
    from va_plugin.data.images import write_image
    from va_plugin.eval.evaluate import load_mesh
    from va_plugin.export.render import mesh_views

    rows = []
    for name, source in inputs:
        meshes = [out / "runs" / f"{name}-{m}" / "mesh.ply" for m in methods]
        if not any(m.is_file() for m in meshes):
            continue
        image = resolve_dataparser(source).setup().get_outputs("train").images[0].numpy()
        if image.shape[-1] == 4:
            image = image[..., :3] * image[..., 3:] + (1.0 - image[..., 3:])
        tiles = [cv2.resize(image, (resolution, resolution), interpolation=cv2.INTER_AREA)]
        tiles += [mesh_views([load_mesh(m)], frames, resolution) if m.is_file()
                  else np.ones((resolution, frames * resolution, 3), np.float32) for m in meshes]
        rows.append(np.concatenate(tiles, axis=1))
    if not rows:
        return None
    path = out / "generated_meshes.png"
    write_image(path, np.concatenate(rows, axis=0))
    return path


def inconsistency_figure(runs, out: Path, tile: int = 96):
    """One row per view-adaptive run (``(label, run_dir)``): for each training view its input and its
    inconsistency map side by side, cut from the run's ``inconsistency.png`` (input | own | canonical |
    map columns, a row per view); shorter rows are padded with white. Written to
    ``OUT/generated_inconsistency.png``."""
    import cv2
    import numpy as np

    from va_plugin.data.images import read_image, write_image

    rows = []
    for _, run_dir in runs:
        path = run_dir / "inconsistency.png"
        if not path.is_file():
            continue
        picture = read_image(path)[..., :3]
        side = picture.shape[1] // 4
        tiles = []
        for v in range(picture.shape[0] // side):
            block = picture[v * side:(v + 1) * side]
            tiles.extend(cv2.resize(block[:, column * side:(column + 1) * side], (tile, tile),
                                    interpolation=cv2.INTER_AREA) for column in (0, 3))
        rows.append(np.concatenate(tiles, axis=1))
    if not rows:
        return None
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=1.0) for r in rows]
    path = out / "generated_inconsistency.png"
    write_image(path, np.concatenate(rows, axis=0))
    return path


def write_tables(rows, out: Path) -> None:
    (out / "generated.json").write_text(json.dumps(rows, indent=2))
    lines = ["| input | method | steps | wall s | train PSNR | shared path on the inputs | silhouette IoU | per-view "
             "PSNR spread after phase 1 (dB) | adaptive phases | inconsistency per view |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        iou = (f"{r['silhouette_iou_mean']:.3f} / {r['silhouette_iou_min']:.3f}"
               if "silhouette_iou_mean" in r else "")
        inc = ", ".join(f"{v:.2g}" for v in r["inconsistency"]) if r.get("inconsistency") else ""
        lines.append(f"| {r['input']} | {r['method']} | {r.get('steps', '')} | {r['wall_seconds']:.0f} | "
                     f"{r.get('train_psnr', float('nan')):.2f} | {r.get('shared_path_psnr') or ''} | {iou} | "
                     f"{r.get('residual_spread_db', '')} | "
                     f"{r.get('adaptive_phases', '')} | {inc} |")
    (out / "generated.md").write_text("\n".join(lines) + "\n")


@friendly_errors
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-root", type=Path, default=DEFAULT_GENERATED_ROOT)
    parser.add_argument("--out", type=Path, default=REPO / "outputs" / "generated")
    parser.add_argument("--methods", default="neus,va-neus")
    parser.add_argument("--inputs", default="", help="comma-separated input names (default: all)")
    parser.add_argument("--steps", type=int, default=None, help="step budget (default: each method's)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--resume", action="store_true")
    parser.add_argument("--force-adaptive", action="store_true",
                        help="run the adaptive phases even where the consistent-scene test would skip them "
                             "(runs and rows are named METHOD-forced)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a config override of every run (as va-train's --set; repeatable); needs --label")
    parser.add_argument("--label", default="", help="suffix of the runs' and rows' names (METHOD-LABEL), "
                                                    "for a variant made with --set")
    parser.add_argument("--figure-only", action="store_true", help="only rebuild tables and figures")
    args = parser.parse_args(argv)
    if args.set and not args.label:
        parser.error("--set changes the runs: name them with --label (rows are named METHOD-LABEL)")
    if args.label and not args.label.replace("-", "").replace("_", "").isalnum():
        parser.error(f"--label must be letters, digits, '-' or '_', got {args.label!r}")

    inputs = generator_outputs(args.data_root)
    if args.inputs:
        wanted = set(args.inputs.split(","))
        unknown = wanted - {name for name, _ in inputs}
        if unknown:
            raise SystemExit(f"error: unknown inputs {sorted(unknown)}; found {[n for n, _ in inputs]}")
        inputs = [(n, p) for n, p in inputs if n in wanted]
    methods = args.methods.split(",")
    (args.out / "runs").mkdir(parents=True, exist_ok=True)
    rows_path = args.out / ROWS_FILE
    done = keyed_rows(rows_path, lambda row: (row["input"], row["method"]))

    def tag_of(method: str) -> str:
        tag = f"{method}-forced" if args.force_adaptive and method.startswith("va-") else method
        return f"{tag}-{args.label}" if args.label else tag

    total = len(inputs) * len(methods)
    start = time.perf_counter()
    for k, ((name, source), method) in enumerate(((i, m) for i in inputs for m in methods), 1):
        tag = tag_of(method)
        run_dir = args.out / "runs" / f"{name}-{tag}"
        key = (source.parent.name + "/" + source.name, tag)
        if args.figure_only or (args.resume and key in done and (run_dir / "mesh.ply").is_file()):
            continue
        elapsed = time.perf_counter() - start
        print(f"[{k}/{total} | {elapsed / 60:.0f} min elapsed] {key[0]}: {tag}", flush=True)
        seconds = run_one(method, source, run_dir, args)
        row = {"input": key[0], "method": tag, "wall_seconds": round(seconds, 1),
               "threads": args.threads, **last_metrics(run_dir), **rig_check(source)}
        inc = inconsistency_summary(run_dir)
        if inc is not None:
            row["inconsistency"] = inc
            shutil.copy(run_dir / "inconsistency.png", args.out / f"{name}-{tag}_inconsistency.png")
        done[key] = row
        append_row(rows_path, row)
        print(f"    done in {seconds:.0f} s: train PSNR {row.get('train_psnr', float('nan')):.2f}, "
              f"adaptive: {row.get('adaptive_phases', '-')}", flush=True)

    rows = [done[k] for k in sorted(done)]
    for row in rows:  # the maps' summary is re-read, so rows written by older versions get its precision
        name = Path(row["input"]).stem
        run_dir = args.out / "runs" / f"{name}-{row['method']}"
        inc = inconsistency_summary(run_dir)
        if inc is not None:
            row["inconsistency"] = inc
        if (run_dir / "view_residuals.json").is_file():  # the consistent-scene test's measurement
            views = json.loads((run_dir / "view_residuals.json").read_text())["views"]
            row["residual_spread_db"] = round(residual_spread_db(views), 2)
        row["shared_path_psnr"] = shared_path_psnr(run_dir)
    write_tables(rows, args.out)
    # every run in the folder, this call's first: a second call with other --methods keeps the first's
    figure = summary_figure(inputs, list(dict.fromkeys([tag_of(m) for m in methods] + [r["method"] for r in rows])),
                            args.out)
    if figure is not None:
        print(f"wrote {figure}")
    adaptive_runs = [(f"{name} {r['method']}", args.out / "runs" / f"{name}-{r['method']}")
                     for r in rows for name in [Path(r["input"]).stem] if r["method"].startswith("va-")]
    figure = inconsistency_figure(adaptive_runs, args.out)
    if figure is not None:
        labels = ", ".join(label for label, d in adaptive_runs if (d / "inconsistency.png").is_file())
        print(f"wrote {figure} (rows: {labels})")
    print(f"wrote {args.out / 'generated.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
