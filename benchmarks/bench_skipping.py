"""What skipping buys (issue 4): ``ngp`` and ``neus`` trained with each kind of skipping on and off.

For every variant below the script trains the method's default run on one scene (its ``va-train``
arguments, trained in this process by ``train_run``), evaluates it (``va-eval`` in a subprocess:
PSNR/SSIM/LPIPS on the held-out views, CD/IoU/F-score of the mesh) and reads the samples per ray the model logged. Whole-run iterations per second are noisy on a
shared machine, so it then times the trained runs again side by side: in one process, it continues
every run for ``--timing-steps`` steps in turn, for ``--timing-rounds`` rounds (the order rotates each
round), and reports the median seconds per step of each. Everything goes into one JSON file.

    python benchmarks/bench_skipping.py [--data DIR] [--work /tmp/va-bench-skipping]
        [--out benchmarks/results/skipping.json] [--only NAME ...] [--image-scale 0.5] [--steps N]

Without ``--data`` the embedded default scene is used (built into ``$VA_PLUGIN_CACHE`` on first use).
Run folders are reused: an interrupted run continues, a finished one is only evaluated, one with an
``eval.json`` is taken as it is (``--fresh`` starts them all again).
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Dict, List, Sequence

import torch

from va_plugin.cli.train import build_parser, make_config
from va_plugin.engine.metrics_log import training_records
from va_plugin.engine.trainer import list_checkpoints, train_run
from va_plugin.registry import discover_methods

NO_GRID = ["--set", "pipeline.model.occupancy_grid.enabled=false"]
NO_EARLY_STOP = ["--set", "pipeline.model.early_stop_transmittance=0"]
VARIANTS: Dict[str, tuple] = {
    "ngp": ("ngp", []),
    "ngp-no-grid": ("ngp", NO_GRID),
    "ngp-no-early-stop": ("ngp", NO_EARLY_STOP),
    "ngp-no-skipping": ("ngp", NO_GRID + NO_EARLY_STOP),
    "ngp-fast": ("ngp", ["--preset", "fast"]),
    "neus": ("neus", []),
    "neus-no-ray-skip": ("neus", ["--set", "pipeline.model.skip_empty_rays=false"]),
    "neus-far-samples": ("neus", ["--set", "pipeline.model.skip_far_samples=true"]),
}
"""name -> (method, extra ``va-train`` arguments); a method's own name is its default run."""

EVAL_KEYS = ("psnr", "ssim", "lpips", "cd", "iou", "fscore")


def cli(name: str) -> str:
    """A console script of this environment (next to the running interpreter)."""
    return str(Path(sys.executable).parent / name)


def train_arguments(name: str, run_dir: Path, data: Path | None, steps: int | None,
                    common: Sequence[str] = ()) -> List[str]:
    """The ``va-train`` arguments of variant ``name`` (the ``common`` overrides before its own)."""
    method, extra = VARIANTS[name]
    arguments = [method, "--output-dir", str(run_dir), "--no-progress"]
    arguments += [] if data is None else ["--data", str(data)]
    arguments += [] if steps is None else ["--steps", str(steps)]
    for override in common:
        arguments += ["--set", override]
    return arguments + extra


def train_and_evaluate(name: str, arguments: List[str], run_dir: Path, image_scale: float, fresh: bool) -> None:
    """Train variant ``name`` into ``run_dir`` (an interrupted run continues, a finished one is kept)
    and write its ``eval.json`` unless it has one."""
    if fresh:
        shutil.rmtree(run_dir, ignore_errors=True)
    if (run_dir / "eval.json").is_file():
        return
    print(f"[{name}] training: va-train {' '.join(arguments)} --resume", flush=True)
    methods = discover_methods()
    train_run(make_config(build_parser(methods).parse_args(arguments), methods), resume=True)
    print(f"[{name}] evaluating", flush=True)
    subprocess.run([cli("va-eval"), "--load-dir", str(run_dir), "--image-scale", str(image_scale), "--no-progress"],
                   check=True)


def summarise_run(run_dir: Path) -> Dict[str, object]:
    """Training time, logged samples per ray and the eval metrics of a finished run."""
    train = training_records(run_dir)
    last = train[-1]
    out: Dict[str, object] = {"steps": last["step"], "train_seconds": last["train_seconds"],
                              "it_per_s_whole_run": round(last["step"] / last["train_seconds"], 3)}
    for key in ("samples_per_ray", "probed_per_ray"):
        values = [r[key] for r in train if key in r]
        if values:
            # logged every 25 steps: the mean over the log is the run's mean up to sampling
            out[f"{key}_mean"] = round(statistics.fmean(values), 2)
            out[f"{key}_final"] = values[-1]
    evaluation = json.loads((run_dir / "eval.json").read_text())
    out.update({k: evaluation[k] for k in EVAL_KEYS if k in evaluation})
    out["eval_image_params"] = evaluation.get("image_params")
    return out


@torch.no_grad()
def rendered_ray_shares(trainer, batches: int = 8) -> Dict[str, float]:
    """Shares of the background (mask < 0.5) and foreground rays of ``batches`` training batches that a
    trained run renders at all: a skipped ray (empty-ray test, or no sample left) has accumulation 0."""
    counts = {"background": [0, 0], "foreground": [0, 0]}
    for _ in range(batches):
        rays, batch = trainer.pipeline.datamanager.next_train(trainer.step)
        rendered = trainer.model.render_rays(rays, keys=("accumulation",))["accumulation"][:, 0] > 0
        background = batch["mask"][:, 0] < 0.5
        for key, rows in (("background", background), ("foreground", ~background)):
            counts[key][0] += int((rendered & rows).sum())
            counts[key][1] += int(rows.sum())
    return {f"{key}_rays_rendered": round(hit / max(total, 1), 3) for key, (hit, total) in counts.items()}


def interleaved_step_seconds(runs: Dict[str, tuple], work: Path, rounds: int, steps: int) -> Dict[str, Dict]:
    """Median seconds per training step of each trained run (name -> (run folder, its ``va-train``
    arguments)), continued ``steps`` steps at a time in turn (``rounds`` rounds, rotating the order),
    on copies of the runs; also the share of training rays each run renders at the end of training."""
    methods = discover_methods()
    trainers = {}
    for name, (run_dir, arguments) in runs.items():
        copy_dir = work / "timing" / name
        shutil.rmtree(copy_dir, ignore_errors=True)
        (copy_dir / "checkpoints").mkdir(parents=True)
        shutil.copy2(list_checkpoints(run_dir)[-1], copy_dir / "checkpoints")
        # the config is rebuilt from the command line, as va-train does (a pickled one may predate
        # fields added since)
        config = make_config(build_parser(methods).parse_args(arguments), methods)
        config.output_dir, config.log_every = copy_dir, 10 ** 9
        config.checkpoint_every, config.keep_checkpoints = 10 ** 9, 1
        trainer = config.setup()
        trainer.resume()
        trainers[name] = trainer
    shares = {name: rendered_ray_shares(trainer) for name, trainer in trainers.items()}
    per_step: Dict[str, List[float]] = {name: [] for name in trainers}
    names = list(trainers)
    for r in range(rounds + 1):  # round 0 warms up every run and is not counted
        for name in names[r % len(names):] + names[:r % len(names)]:
            trainer = trainers[name]
            before = trainer.train_seconds
            trainer.config.max_steps = trainer.step + steps
            trainer.train()
            if r > 0:
                per_step[name].append((trainer.train_seconds - before) / steps)
    return {name: {"median_s_per_step": round(statistics.median(v), 4),
                   "it_per_s": round(1.0 / statistics.median(v), 3), **shares[name],
                   "s_per_step_all": [round(x, 4) for x in v]} for name, v in per_step.items()}


def ratios(results: Dict[str, Dict]) -> Dict[str, float]:
    """Speed and sample-count ratios of each variant against its method's default."""
    out = {}
    for name, row in results.items():
        base = VARIANTS[name][0]
        if name == base or base not in results:
            continue
        ref = results[base]
        if "timing" in row and "timing" in ref:
            out[f"{base} / {name} it/s"] = round(ref["timing"]["it_per_s"] / row["timing"]["it_per_s"], 2)
        if row.get("samples_per_ray_mean") and ref.get("samples_per_ray_mean"):
            out[f"{name} / {base} samples per ray"] = round(row["samples_per_ray_mean"] / ref["samples_per_ray_mean"], 2)
    if "ngp" in results and "neus" in results and "timing" in results["ngp"] and "timing" in results["neus"]:
        out["ngp / neus it/s"] = round(results["ngp"]["timing"]["it_per_s"] / results["neus"]["timing"]["it_per_s"], 2)
    return out


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=None, help="scene folder (default: the embedded default scene)")
    parser.add_argument("--work", type=Path, default=Path("/tmp/va-bench-skipping"), help="run folders")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/skipping.json"))
    parser.add_argument("--only", nargs="+", choices=sorted(VARIANTS), default=list(VARIANTS))
    parser.add_argument("--image-scale", type=float, default=0.5, help="held-out views are rendered at this scale")
    parser.add_argument("--timing-rounds", type=int, default=5)
    parser.add_argument("--timing-steps", type=int, default=10)
    parser.add_argument("--steps", type=int, default=None, help="step budget of every run (default: the method's)")
    parser.add_argument("--set", dest="common", action="append", default=[], metavar="PATH=VALUE",
                        help="an override for every run (before the variant's own)")
    parser.add_argument("--fresh", action="store_true", help="start every run again (deletes its folder)")
    args = parser.parse_args(argv)

    started = time.time()
    run_dirs = {name: args.work / name for name in args.only}
    report = {
        "command": "python benchmarks/bench_skipping.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "scene": str(args.data) if args.data is not None else "embedded default scene (mug, level 2)",
        "machine": {"cpus": torch.get_num_threads(), "platform": platform.platform(), "torch": torch.__version__},
        "variants": {name: {"method": VARIANTS[name][0], "arguments": VARIANTS[name][1]} for name in args.only},
        "results": {},
    }

    def write() -> None:  # after every run, so that a long benchmark leaves what it has measured
        report["ratios"] = ratios(report["results"])
        report["wall_seconds"] = round(time.time() - started, 1)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=2) + "\n")

    results = report["results"]
    arguments = {name: train_arguments(name, run_dir, args.data, args.steps, args.common)
                 for name, run_dir in run_dirs.items()}
    for name, run_dir in run_dirs.items():
        train_and_evaluate(name, arguments[name], run_dir, args.image_scale, args.fresh)
        results[name] = summarise_run(run_dir)
        write()
    if args.timing_rounds > 0:
        print("timing the trained runs side by side", flush=True)
        runs = {name: (run_dirs[name], train_arguments(name, args.work / "timing" / name, args.data, args.steps,
                                                      args.common)) for name in run_dirs}
        for name, timing in interleaved_step_seconds(runs, args.work, args.timing_rounds, args.timing_steps).items():
            results[name]["timing"] = timing
        write()
    print(json.dumps({"results": {k: {m: v.get(m) for m in ("it_per_s_whole_run", "samples_per_ray_mean", "cd",
                                                            "psnr")} for k, v in results.items()},
                      "ratios": report["ratios"]}, indent=1))
    print(f"written to {args.out}")

if __name__ == "__main__":
    main()
