"""Speed (issue 9): error against wall-clock training time, and where the time of a training step goes.

For each method the script trains one run on one scene, writing a checkpoint every ``steps / N`` steps,
and evaluates every checkpoint afterwards (Chamfer distance of the extracted mesh, PSNR of held-out
views). The seconds of the curve are the trainer's own clock, which counts training steps only:
checkpoint writing and evaluation are off it. Per method it reports

* the curve (training seconds, step, CD, PSNR) and the first checkpoint from which the CD stays within
  110% of the final CD (at checkpoint resolution: an upper bound on the time to get there; the first
  checkpoint that touches 110% is in the JSON as ``first_touch_seconds``);
* iterations per second of the whole run, and the mean over its log of the samples per ray evaluated
  with gradients (``samples_per_ray`` in metrics.jsonl);
* a breakdown of one training step: from the trained state (a view-adaptive run is then in its last
  phase), a few warm-up steps and then ``--timing-steps`` steps with the stage markers of
  :mod:`va_plugin.utils.stages` on (data, sampling, encoding, MLPs, SDF gradient, rendering, backward,
  optimizer, health checks, callbacks, other). Stage times are exclusive (an encoding evaluated while
  sampling counts as encoding) and are medians over the timed steps; on CUDA every stage boundary
  synchronizes the device, so the breakdown's step time is a little above the run's.

Writes into OUT: ``speed.json`` (machine, device, command, every number above), ``speed.png`` (CD and
PSNR against training seconds), ``speed_stages.png`` (stacked bars of the stage times), ``speed.md``
(the tables) and ``runs/METHOD`` (the run folders, with their last checkpoint).

    python benchmarks/run_speed.py [--methods neus ngp va-neus va-ngp] [--data DIR] [--steps N]
        [--preset fast] [--checkpoints 8] [--threads 2] [--device auto|cpu|cuda] [--out outputs/speed]
        [--smoke]

Without ``--data`` the embedded default scene (the mug, 4 views at 256 px, level 2) is used. ``--smoke``
checks the plumbing in seconds: a 32-px scene (built once into ``$VA_PLUGIN_CACHE/bench-scenes``), a few
steps, a tiny evaluation (the test suite runs it).
"""

from __future__ import annotations

import argparse
import math
import shlex
import shutil
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, replace
from datetime import datetime
from pathlib import Path
from typing import Any

import torch

from va_plugin.api import build_config
from va_plugin.bench.catalog import SceneSpec, ensure_scene
from va_plugin.bench.experiment import duration
from va_plugin.bench.presets import BACKBONES, EvalSettings, get_preset
from va_plugin.bench.report import fmt, machine_info, markdown_table, plot_stacked_bars, plot_time_curves, write_json
from va_plugin.bench.rows import ADAPTIVE_OVERRIDES, checkpoint_along, evaluate_checkpoints
from va_plugin.bench.scenes import cache_dir, default_scene
from va_plugin.bench.speed import CD_FACTOR, STAGES, logged_means, stage_breakdown, time_to_reach
from va_plugin.cli.common import friendly_errors
from va_plugin.config import apply_override
from va_plugin.engine.trainer import list_checkpoints
from va_plugin.errors import ConfigError
from va_plugin.registry import get_method
from va_plugin.utils.device import pick_device

DEFAULT_METHODS = ("neus", "ngp", "va-neus", "va-ngp")
SMOKE_ADAPTIVE = ("pipeline.model.field.skip_consistent_scenes=false",)
"""Smoke runs go through every phase without the consistency check (which renders every input view)."""
EVALUATION = get_preset("quick").evaluation
"""Default evaluation of a checkpoint, the quick benchmark preset's: 4 held-out views at a quarter of their
size, a 96^3 mesh, CD on 100k surface samples."""


# -- configs ---------------------------------------------------------------------------------------
def backbone_of(method: str) -> str | None:
    """The backbone a registered method wraps (``neus`` for ``va-neus``), None for other methods."""
    return next((b for b, names in BACKBONES.items() if method in names), None)


def method_config(method: str, args: argparse.Namespace, scene: Path | None, run_dir: Path):
    """The trainer config of one method's run, as ``va-train`` builds it from the same flags, with a
    checkpoint every ``steps / --checkpoints`` steps."""
    overrides = list(get_preset("smoke").overrides_for(backbone_of(method) or "")) if args.smoke else []
    data = scene if scene is not None else default_scene()
    config = build_config(method, data, out=run_dir, progress=False, seed=args.seed, device=args.device,
                          preset=args.preset or None, steps=args.steps, overrides=[*overrides, *args.overrides])
    if hasattr(config.pipeline.model.field, "diagnostics_scale"):  # view-adaptive: no pictures on the clock
        for override in ADAPTIVE_OVERRIDES + (SMOKE_ADAPTIVE if args.smoke else ()):
            apply_override(config, override)
    checkpoint_along(config, args.checkpoints)
    config.log_every = max(1, min(config.log_every, config.max_steps // 20))
    config.progress = sys.stderr.isatty()
    return config


def measure(method: str, config, scene_dir: Path, args: argparse.Namespace, evaluation: EvalSettings,
            say) -> dict[str, Any]:
    """Train, time the stages, evaluate the checkpoints: one method's entry of the report."""
    run_dir = Path(config.output_dir)
    shutil.rmtree(run_dir, ignore_errors=True)
    trainer = config.setup()
    say(f"{method}: training {config.max_steps} steps on {trainer.device}, a checkpoint every "
        f"{config.checkpoint_every}")
    trainer.train()
    train_seconds, steps = trainer.train_seconds, trainer.step
    say(f"{method}: trained in {train_seconds:.1f} s ({steps / train_seconds:.2f} it/s); timing the stages of "
        f"{args.timing_steps} more steps")
    breakdown = stage_breakdown(trainer, args.warmup_steps, args.timing_steps)
    started = time.perf_counter()
    points = evaluate_checkpoints(trainer.pipeline, run_dir, scene_dir, evaluation, config.checkpoint_every,
                                  config.max_steps)
    curve = [{"train_seconds": round(p["train_seconds"], 3), "step": p["steps"], "cd": p.get("cd", float("nan")),
              "psnr": p.get("psnr", float("nan"))} for p in points]
    eval_seconds = time.perf_counter() - started
    for path in list_checkpoints(run_dir)[:-1]:  # an ngp checkpoint is tens of MB
        path.unlink()
    reach = time_to_reach(curve)
    logged = logged_means(run_dir, ("samples_per_ray", "probed_per_ray"))
    result = {
        "method": method, "variant": method, "steps": steps, "train_seconds": round(train_seconds, 3),
        "it_per_s": round(steps / train_seconds, 4), "samples_per_ray": logged["samples_per_ray"],
        "probed_per_ray": logged["probed_per_ray"], "cd": curve[-1]["cd"], "psnr": curve[-1]["psnr"],
        "time_to_110pct_cd": reach, "curve": curve, "breakdown": breakdown,
        "eval_seconds": round(eval_seconds, 2), "run_dir": str(run_dir),
    }
    problems = [p[k] for p in points[-1:] for k in ("error", "lpips_missing") if k in p]
    if problems:
        result["note"] = "; ".join(problems)
    say(f"{method}: evaluated {len(curve)} checkpoints in {eval_seconds:.0f} s: CD {fmt(result['cd'], 'cd')}, "
        f"PSNR {fmt(result['psnr'], 'psnr')}, CD within {CD_FACTOR:.0%} of the final from then on after "
        f"{seconds(reach['train_seconds'])} s")
    return result


# -- report ------------------------------------------------------------------------------------------
def seconds(value: float | None) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.1f}"


def tables(rows: Sequence[dict[str, Any]]) -> list[str]:
    summary = markdown_table(
        ["Method", "steps", "train s", "it/s", "samples/ray", "CD", "PSNR",
         f"s until CD stays within {CD_FACTOR:.0%} of final"],
        [[r["method"], r["steps"], seconds(r["train_seconds"]), f"{r['it_per_s']:.2f}",
          fmt(r["samples_per_ray"], "samples"), fmt(r["cd"], "cd"), fmt(r["psnr"], "psnr"),
          f"{seconds(r['time_to_110pct_cd']['train_seconds'])} (step {r['time_to_110pct_cd']['step']})"]
         for r in rows])
    names = (*STAGES, "other")
    breakdown = markdown_table(
        ["Method", "step ms", *names],
        [[r["method"], f"{1000 * r['breakdown']['step_seconds']:.1f}",
          *(f"{1000 * r['breakdown']['stages'][n]:.1f} "
            f"({r['breakdown']['stages'][n] / r['breakdown']['step_seconds']:.0%})"
            for n in names)] for r in rows])
    inclusive = markdown_table(
        ["Method", *STAGES], [[r["method"], *(f"{1000 * r['breakdown']['inclusive'][n]:.1f}" for n in STAGES)]
                              for r in rows])
    return [summary, "Median milliseconds per training step and stage (exclusive times, share of the step):",
            breakdown, "The same, inclusive (a stage with the encodings and MLPs it calls; these overlap):",
            inclusive]


def write_report(rows: list[dict[str, Any]], out: Path, meta: dict[str, Any], plots: bool = True) -> list[Path]:
    """speed.json and speed.md, and with ``plots`` the two pictures."""
    out.mkdir(parents=True, exist_ok=True)
    written = [write_json(rows, out / "speed.json", meta)]
    lines = ["# Speed: error against training time, and the stages of a step", "",
             f"- command: `{meta['command']}`", f"- date: {meta['date']}; device: {meta['device']}",
             f"- machine: {meta['machine']['cpus']} CPU cores, torch {meta['machine']['torch']} with "
             f"{meta['machine']['torch_threads']} threads; {meta['machine']['platform']}",
             f"- scene: {meta['scene']}; method preset: {meta['preset'] or 'default'}; {meta['checkpoints']} "
             f"checkpoints per run evaluated ({meta['evaluation']})", "", *tables(rows), "",
             "![CD and PSNR against training seconds](speed.png)", "![stages](speed_stages.png)"]
    (out / "speed.md").write_text("\n".join(lines) + "\n")
    written.append(out / "speed.md")
    if not plots:
        return written
    paths = (plot_time_curves(rows, out / "speed.png", "Error against training seconds (evaluation off the clock)"),
             plot_stacked_bars({r["method"]: {n: 1000 * s for n, s in r["breakdown"]["stages"].items()}
                                for r in rows}, out / "speed_stages.png",
                               "Median time per training step, by stage (exclusive)", "milliseconds"))
    written.extend(path for path in paths if path is not None)
    return written


# -- command line ------------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--methods", nargs="+", default=list(DEFAULT_METHODS),
                        help=f"registered methods to run (default: {' '.join(DEFAULT_METHODS)})")
    parser.add_argument("--data", type=Path, default=None, help="scene folder (default: the embedded default scene)")
    parser.add_argument("--steps", type=int, default=None, help="step budget of every run (default: each method's)")
    parser.add_argument("--preset", default=None, help="method preset applied to every method (e.g. fast)")
    parser.add_argument("--checkpoints", type=int, default=None,
                        help="checkpoints evaluated along each run (default 8; 2 with --smoke)")
    parser.add_argument("--timing-steps", type=int, default=None,
                        help="steps timed stage by stage after training (default 10; 3 with --smoke)")
    parser.add_argument("--warmup-steps", type=int, default=None, help="untimed steps before them (default 3; 1)")
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")
    parser.add_argument("--device", default="auto", help="auto, cpu or cuda[:N]")
    parser.add_argument("--seed", type=int, default=42)
    parser.add_argument("--image-scale", type=float, default=None,
                        help="held-out views are scored at this fraction of their size "
                             f"(default {EVALUATION.image_scale})")
    parser.add_argument("--eval-views", type=int, default=None,
                        help=f"held-out views scored (default {EVALUATION.max_views}; the first ones)")
    parser.add_argument("--mesh-resolution", type=int, default=None,
                        help=f"marching-cubes grid of the meshes scored (default {EVALUATION.mesh_resolution})")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="PATH=VALUE",
                        help="a config override for every method (as va-train --set)")
    parser.add_argument("--out", type=Path, default=None, help="results folder (default outputs/speed[-smoke])")
    parser.add_argument("--smoke", action="store_true",
                        help="plumbing check in seconds: a 32-px scene, 4 steps, a tiny evaluation")
    return parser


def settle(args: argparse.Namespace) -> EvalSettings:
    """Fill the defaults that depend on --smoke, check the flags; the evaluation settings."""
    smoke = get_preset("smoke")
    for name, normal, small in (("checkpoints", 8, 2), ("timing_steps", 10, 3), ("warmup_steps", 3, 1)):
        if getattr(args, name) is None:
            setattr(args, name, small if args.smoke else normal)
    if args.smoke and args.steps is None:
        args.steps = 4
    if args.out is None:
        args.out = Path("outputs") / ("speed-smoke" if args.smoke else "speed")
    for name, least in (("steps", 1), ("checkpoints", 1), ("timing_steps", 1), ("warmup_steps", 0),
                        ("eval_views", 1), ("mesh_resolution", 8)):
        value = getattr(args, name)
        if value is not None and value < least:
            raise ConfigError(f"--{name.replace('_', '-')} must be at least {least}, got {value}")
    if args.image_scale is not None and not args.image_scale > 0:
        raise ConfigError(f"--image-scale must be positive, got {args.image_scale}")
    for method in args.methods:
        get_method(method)  # unknown method: the registry's error, with the known ones
    if args.data is not None and not args.data.exists():
        raise ConfigError(f"scene folder not found: {args.data}")
    pick_device(args.device)  # refuse a missing CUDA device before anything is trained
    evaluation = smoke.evaluation if args.smoke else EVALUATION
    if args.image_scale is not None:
        evaluation = replace(evaluation, image_scale=args.image_scale)
    if args.mesh_resolution is not None:
        evaluation = replace(evaluation, mesh_resolution=args.mesh_resolution)
    if args.eval_views is not None:
        evaluation = replace(evaluation, max_views=args.eval_views)
    return evaluation


def run(args: argparse.Namespace, command: str) -> int:
    evaluation = settle(args)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    started = time.perf_counter()

    def say(text: str) -> None:
        print(f"[{duration(time.perf_counter() - started)}] {text}", flush=True)

    out = args.out.resolve()
    scene = args.data
    if scene is None and args.smoke:
        smoke = get_preset("smoke")
        spec = SceneSpec("procedural:mug", smoke.level, smoke.views, smoke.resolution, args.seed,
                         smoke.scene_mesh_resolution)
        if not (cache_dir() / "bench-scenes" / spec.folder_name / "scene.json").is_file():
            say(f"building the {smoke.resolution}-px smoke scene")
        scene = ensure_scene(spec, cache_dir() / "bench-scenes", None)
    configs = {m: method_config(m, args, scene, out / "runs" / m) for m in args.methods}  # all checked first
    scene_dir = Path(next(iter(configs.values())).pipeline.datamanager.dataparser.data)
    machine = machine_info()
    device = pick_device(args.device)
    meta: dict[str, Any] = {
        "command": command, "date": datetime.now().strftime("%Y-%m-%d %H:%M"), "machine": machine,
        "device": f"{device}" + (f" ({torch.cuda.get_device_name(device)})" if device.type == "cuda" else ""),
        "scene": str(scene_dir) if args.data is not None or args.smoke else f"embedded default scene ({scene_dir})",
        "preset": args.preset, "smoke": args.smoke, "methods": list(args.methods),
        "steps": {m: c.max_steps for m, c in configs.items()}, "checkpoints": args.checkpoints,
        "evaluation": asdict(evaluation), "cd_factor": CD_FACTOR, "stages": [*STAGES, "other"],
    }
    say(f"speed benchmark: {', '.join(args.methods)} on {meta['scene']}; results in {out}")
    rows: list[dict[str, Any]] = []
    written: list[Path] = []
    for index, (method, config) in enumerate(configs.items()):
        say(f"method {index + 1}/{len(configs)}: {method}")
        rows.append(measure(method, config, scene_dir, args, evaluation, say))
        meta["wall_seconds"] = round(time.perf_counter() - started, 1)
        written = write_report(rows, out, meta, plots=len(rows) == len(configs))  # plots once, at the end
    print("\n" + "\n\n".join(tables(rows)))
    print("files: " + ", ".join(str(p) for p in written))
    return 0


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark (``error: ...`` and exit 2 on bad input, 130 on Ctrl-C)."""
    arguments = sys.argv[1:] if argv is None else list(argv)
    command = " ".join(["python benchmarks/run_speed.py", *(shlex.quote(a) for a in arguments)])

    @friendly_errors
    def entry() -> int:
        return run(build_parser().parse_args(arguments), command)

    return entry()


if __name__ == "__main__":
    sys.exit(main())
