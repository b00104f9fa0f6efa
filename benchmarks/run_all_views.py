"""Every view against the paper's four: the `neus` default on GSO objects trained on 4 and on 16 rig views,
scored on the same held-out views off the rig (elevations 0 and 45 degrees, azimuths between the rig's),
which no view count trains on.

The GSO renders exist only on the rig, so the off-rig views show the ground-truth mesh with a texture baked
from the 16 clean renders (``ImageSource.baked_renderer``); the script also reports how closely that
texture reproduces the rig's own renders. Each row: CD, IoU (the ground-truth mesh), PSNR, SSIM, LPIPS (the
8 off-rig views), wall seconds from the start of training to the evaluated mesh. Rows go to OUT/rows.jsonl
(a rerun skips finished ones) and the table to OUT/all_views.md.

A variant of the default (``--set KEY=VALUE ... --variant NAME``) is run into the same folder: the table pairs
it with the default at the same view count, object by object, and ``time_accuracy.png`` plots each
configuration's mean PSNR and CD against its mean training seconds.

    python benchmarks/run_all_views.py --data-root ../shared/data/gso [--objects alarm,bell] [--views 4,16]
        [--level 2] [--steps N] [--set KEY=VALUE --variant NAME] [--jobs 2] [--out outputs/bench/all-views]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

METRICS = ("cd", "iou", "psnr", "ssim", "lpips", "wall_seconds", "train_seconds")


def build(root: Path, data_root: Path, name: str, views: int, level: int) -> Path:
    """The object's scene with ``views`` inputs whose held-out views are the off-rig ones only."""
    from va_plugin.bench.scenes.builder import build_scene
    from va_plugin.bench.scenes.rig import view_angles
    from va_plugin.data.rigs import RIG_VIEWS, input_view_ids

    out = root / f"{name}-l{level}-v{views}"
    if (out / "scene.json").is_file():
        return out
    train = input_view_ids(views)
    held_out = [i for i in range(len(view_angles(extra=True))) if i not in train]
    off_rig = [k for k, i in enumerate(held_out) if i >= RIG_VIEWS]
    return build_scene(out, f"gso:{name}", n_views=views, level=level, data_root=data_root, test_views=off_rig,
                       gso_off_rig=True)


MAIN_PROCESS: int | None = None
"""In a worker: the main process (set by :func:`start_worker`)."""


def start_worker(parent: int) -> None:
    """A worker's start: its row is interrupted (a checkpoint saved) if the main process ``parent`` dies."""
    global MAIN_PROCESS
    from va_plugin.utils.interrupts import interrupt_when_orphaned

    MAIN_PROCESS = parent
    # a main process started in the background (``cmd &``) hands its workers SIGINT ignored, and then the
    # SIGINT it forwards on SIGTERM (and the orphan watch's) would not stop their rows at a checkpoint
    signal.signal(signal.SIGINT, signal.default_int_handler)
    interrupt_when_orphaned(parent)


def run_one(job: dict[str, Any]) -> dict[str, Any]:
    """:func:`train_and_score` in a worker; one whose main process is gone ends once its row stopped."""
    try:
        return train_and_score(job)
    except KeyboardInterrupt:
        if MAIN_PROCESS is not None and os.getppid() != MAIN_PROCESS:
            os._exit(130)  # nobody is left to answer, and the pool's queues would hold this process
        raise


def train_and_score(job: dict[str, Any]) -> dict[str, Any]:
    """Train the method's default (``job["method"]``, ``neus`` when absent) on one scene (one torch thread),
    then evaluate its final state."""
    import torch

    from va_plugin.config import apply_override
    from va_plugin.engine.trainer import train_run
    from va_plugin.registry import get_method

    torch.set_num_threads(1)
    config = get_method(job.get("method", "neus")).make_config()
    config.pipeline.datamanager.dataparser.data = Path(job["scene"])
    config.output_dir = Path(job["run_dir"])
    config.progress = False
    if job["steps"]:
        config.max_steps = job["steps"]
    for override in job.get("overrides", ()):
        apply_override(config, override)
    started = time.perf_counter()
    train_run(config, resume=True)
    scores, state = score(job["run_dir"])
    wall = time.perf_counter() - started
    passed = ("key", "object", "views", "level", "arm", "arm_overrides", "method", "seed", "commit", "trains")
    return {**{k: job[k] for k in passed if k in job},
            "variant": job.get("variant", ""), **scores, "steps": int(state["step"]),
            "train_seconds": round(float(state["train_seconds"]), 1), "wall_seconds": round(wall, 1)}


def score(run_dir: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """The scores of a run's final state on its scene (one torch thread), and the checkpoint's state."""
    import torch

    from va_plugin.api import load_run
    from va_plugin.eval.evaluate import evaluate_run

    torch.set_num_threads(1)
    pipeline, state = load_run(Path(run_dir), device="cpu").parts()
    result = evaluate_run(pipeline, state, None, 128, 1.0, None, 100_000, progress=False)
    return {"cd": result["cd"], "iou": result["iou"], "psnr": result["psnr"], "ssim": result["ssim"],
            "lpips": result.get("lpips"), "test_views": result["image_params"]["views"]}, state


def rescore_one(row: dict[str, Any], run_dir: str) -> dict[str, Any]:
    """The row with its scores evaluated again on the run's final state (its scene as it is now); its
    seconds stay those of the run."""
    return {**row, **score(run_dir)[0]}


def texture_fidelity(scene: Path) -> float:
    """PSNR of the baked ground-truth texture rendered at the rig's views against the renders (on white)."""
    from va_plugin.bench.scenes.rig import benchmark_cameras
    from va_plugin.bench.scenes.sources import load_source
    from va_plugin.eval.image import psnr

    info = json.loads((scene / "scene.json").read_text())
    source = load_source(info["source"], info["resolution"], Path(info["source_info"]["data_root"]), gso_off_rig=True)
    rig = benchmark_cameras(info["resolution"], extra=False)
    renderer = source.baked_renderer(rig)
    scores = []
    for k in range(len(rig)):
        baked, real = renderer.render(rig, k), source.images[k]
        scores.append(psnr(baked[..., :3] * baked[..., 3:] + 1 - baked[..., 3:],
                           real[..., :3] * real[..., 3:] + 1 - real[..., 3:]))
    return float(np.mean(scores))


def table(rows: list[dict[str, Any]], configs: list[tuple[int, str]]) -> str:
    """Per object, each configuration's (view count, variant) row; then each configuration paired with the
    default at its view count (a variant) or with the first configuration (a view count)."""
    name = lambda c: f"{c[0]} views" + (f" {c[1]}" if c[1] else "")
    objects = sorted({r["object"] for r in rows})
    by = {(r["object"], r["views"], r.get("variant", "")): r for r in rows}
    lines = ["| object | " + " | ".join(f"{name(c)}: CD / IoU / PSNR / LPIPS / wall s" for c in configs) + " |",
             "|---|" + "---|" * len(configs)]
    for o in objects:
        cells = [" / ".join(f"{by[(o, *c)][m]:.4g}" for m in ("cd", "iou", "psnr", "lpips", "wall_seconds"))
                 if (o, *c) in by else "-" for c in configs]
        lines.append(f"| {o} | " + " | ".join(cells) + " |")
    for c in configs[1:]:
        base = (c[0], "") if c[1] and (c[0], "") in configs else configs[0]
        paired = [o for o in objects if (o, *base) in by and (o, *c) in by]
        if not paired:
            continue
        ratio = lambda m, c=c, base=base, paired=paired: (np.mean([by[(o, *c)][m] for o in paired])
                                                          / np.mean([by[(o, *base)][m] for o in paired]))
        diff = lambda m, c=c, base=base, paired=paired: np.mean([by[(o, *c)][m] - by[(o, *base)][m] for o in paired])
        better = sum(by[(o, *c)]["cd"] < by[(o, *base)]["cd"] for o in paired)
        worst_db = min(by[(o, *c)]["psnr"] - by[(o, *base)]["psnr"] for o in paired)
        worst_cd = max(by[(o, *c)]["cd"] / by[(o, *base)]["cd"] for o in paired)
        lines.append(f"- {name(c)} against {name(base)}, paired over {len(paired)} objects: CD x{ratio('cd'):.3f} "
                     f"(lower on {better}/{len(paired)}; worst x{worst_cd:.3f}), IoU {diff('iou'):+.3f}, "
                     f"PSNR {diff('psnr'):+.2f} dB (worst {worst_db:+.2f}), LPIPS {diff('lpips'):+.4f}, "
                     f"wall x{ratio('wall_seconds'):.3f}, training x{ratio('train_seconds'):.3f}")
    for c in configs:
        present = [o for o in objects if (o, *c) in by]
        if present:
            means = {m: np.mean([by[(o, *c)][m] for o in present]) for m in METRICS}
            lines.append(f"- mean of {name(c)} over {len(present)} objects: " +
                         ", ".join(f"{m} {means[m]:.4g}" for m in METRICS))
    return "\n".join(lines) + "\n"


def time_figure(rows: list[dict[str, Any]], configs: list[tuple[int, str]], path: Path) -> Path | None:
    """Mean PSNR and mean CD against mean training seconds, one point per configuration, over the objects
    that every configuration has (None without matplotlib)."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    by = {(r["object"], r["views"], r.get("variant", "")): r for r in rows}
    objects = sorted(o for o in {r["object"] for r in rows} if all((o, *c) in by for c in configs))
    if not objects:
        return None
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for c in configs:
        wall = np.mean([by[(o, *c)]["train_seconds"] for o in objects])
        for ax, metric in zip(axes, ("psnr", "cd")):
            ax.scatter([wall], [np.mean([by[(o, *c)][metric] for o in objects])])
            ax.annotate(f"{c[0]}v {c[1] or 'default'}", (wall, np.mean([by[(o, *c)][metric] for o in objects])),
                        fontsize=8, xytext=(4, 4), textcoords="offset points")
    for ax, label in zip(axes, ("held-out PSNR (dB), higher is better", "Chamfer distance, lower is better")):
        ax.set_xlabel("training seconds per object (one thread)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    fig.suptitle(f"Mean over {len(objects)} GSO objects")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def rescore(args: argparse.Namespace, done: dict[str, dict[str, Any]], rows_file: Path) -> int:
    """``--rescore``: every scene of OUT built again (its training views must come out the same), then
    every finished run scored on it."""
    import shutil

    from va_plugin.utils.files import write_atomic

    scenes = args.out / "scenes"
    staging = args.out / "scenes.rebuild"
    shutil.rmtree(staging, ignore_errors=True)
    train_views = lambda scene: {p.name: p.read_bytes() for p in (scene / "images").glob("train_*")}
    for scene in sorted(p for p in scenes.iterdir() if p.is_dir()) if scenes.is_dir() else []:
        name, level, views = scene.name.rsplit("-", 2)
        rebuilt = build(staging, args.data_root, name, int(views[1:]), int(level[1:]))
        if train_views(rebuilt) != train_views(scene):  # the old scene stays, the runs stay scorable
            shutil.rmtree(staging)
            sys.exit(f"error: the training views of {scene} changed when rebuilt; retrain instead of rescoring")
    for rebuilt in sorted(staging.iterdir()) if staging.is_dir() else []:
        shutil.rmtree(scenes / rebuilt.name)
        rebuilt.rename(scenes / rebuilt.name)
    shutil.rmtree(staging, ignore_errors=True)
    shutil.copy(rows_file, args.out / "rows.before-rescore.jsonl")
    rows = [r for r in done.values() if (args.out / "runs" / r["key"]).is_dir()]
    with ProcessPoolExecutor(args.jobs, mp_context=get_context("spawn")) as pool:
        new = list(pool.map(rescore_one, rows, [str(args.out / "runs" / r["key"]) for r in rows]))
    for row in new:
        done[row["key"]] = row
        print(json.dumps(row), file=sys.stderr)
    write_atomic(rows_file, "".join(json.dumps(r) + "\n" for r in done.values()))
    return 0


class Terminated(KeyboardInterrupt):
    """SIGTERM reached the main process (not its workers, which a Ctrl-C at a terminal reaches too)."""


def run_rows(jobs: list[dict[str, Any]], n_jobs: int, rows_file: Path, done: dict[str, dict[str, Any]]) -> None:
    """Train and score ``jobs`` in ``n_jobs`` spawned workers, appending each finished row to ``rows_file``.
    Ctrl-C or SIGTERM interrupts the running rows (each saves a checkpoint at the end of its step) and waits
    for them; a worker whose main process was killed interrupts its row by itself."""
    def terminated(signum, frame) -> None:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # a second one ends the process at once
        raise Terminated

    pool = ProcessPoolExecutor(n_jobs, mp_context=get_context("spawn"), initializer=start_worker,
                               initargs=(os.getpid(),))
    previous = signal.signal(signal.SIGTERM, terminated)
    try:
        with open(rows_file, "a") as out:
            for row in pool.map(run_one, jobs):
                out.write(json.dumps(row) + "\n")
                out.flush()
                done[row["key"]] = row
                print(json.dumps(row), file=sys.stderr)
    except KeyboardInterrupt as interrupt:
        if isinstance(interrupt, Terminated):  # pass it on as the interrupt a terminal would have sent them
            for process in list((getattr(pool, "_processes", None) or {}).values()):
                if process.is_alive():
                    os.kill(process.pid, signal.SIGINT)
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    finally:
        signal.signal(signal.SIGTERM, previous)
    pool.shutdown(wait=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-root", type=Path, default=Path("../shared/data/gso"))
    parser.add_argument("--objects", default=None, help="comma-separated GSO names (default: all)")
    parser.add_argument("--views", default="4,16", help="comma-separated view counts (4, 8, 12, 16)")
    parser.add_argument("--level", type=int, default=2)
    parser.add_argument("--steps", type=int, default=0, help="training steps (default: the method's)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="PATH=VALUE",
                        help="config override of every run (repeatable); name the variant with --variant")
    parser.add_argument("--variant", default="", help="name of the overridden variant (part of each row's key)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("outputs/bench/all-views"))
    parser.add_argument("--rescore", action="store_true",
                        help="rebuild OUT's scenes with the current code and score every finished run of OUT again "
                             "(training stays); the old rows go to rows.before-rescore.jsonl")
    args = parser.parse_args(argv)
    from va_plugin.bench.scenes import gso
    from va_plugin.config import apply_override
    from va_plugin.errors import VAError
    from va_plugin.registry import get_method

    try:
        names = args.objects.split(",") if args.objects else gso.list_objects(args.data_root)
        counts = [int(v) for v in args.views.split(",")]
        if args.overrides and not args.variant:
            raise VAError("--set needs --variant NAME, so that the overridden rows keep keys of their own")
        for override in args.overrides:  # a mistyped key fails here, not in every worker
            apply_override(get_method("neus").make_config(), override)
        args.out.mkdir(parents=True, exist_ok=True)
        rows_file = args.out / "rows.jsonl"
        done = {}
        if rows_file.is_file():
            for line in rows_file.read_text().splitlines():
                if line.strip():
                    row = json.loads(line)
                    done[row["key"]] = row
        if args.rescore:
            return rescore(args, done, rows_file)
        jobs = []
        for name in names:
            for views in counts:
                key = f"{name}-l{args.level}-v{views}-s{args.steps or 'default'}" + \
                    (f"-{args.variant}" if args.variant else "")
                if key in done:
                    continue
                scene = build(args.out / "scenes", args.data_root, name, views, args.level)
                jobs.append({"key": key, "object": name, "views": views, "level": args.level, "steps": args.steps,
                             "variant": args.variant, "overrides": list(args.overrides),
                             "scene": str(scene), "run_dir": str(args.out / "runs" / key)})
    except VAError as exc:
        sys.exit(f"error: {exc}")
    print(f"{len(done)} rows done, {len(jobs)} to run with {args.jobs} job(s)", file=sys.stderr)
    try:
        run_rows(jobs, args.jobs, rows_file, done)
    except KeyboardInterrupt:
        print(f"interrupted: {len(done)} rows done; the same command continues (running rows from their "
              "checkpoints)", file=sys.stderr)
        return 130
    fidelity = {n: round(texture_fidelity(args.out / "scenes" / f"{n}-l{args.level}-v{counts[0]}"), 2) for n in names}
    variants = [""] + sorted({r.get("variant", "") for r in done.values()} - {""})
    configs = [(v, variant) for variant in variants for v in counts
               if any(r["views"] == v and r.get("variant", "") == variant for r in done.values())]
    text = table(list(done.values()), configs) + f"\nBaked ground-truth texture at the rig's views, PSNR: {fidelity}\n"
    (args.out / "all_views.md").write_text(text)
    time_figure(list(done.values()), configs, args.out / "time_accuracy.png")
    print(text)
    return 0


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    sys.exit(main())
