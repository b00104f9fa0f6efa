"""Per-step cost of the view-adaptive phases against the wrapped backbone, from a trained state.

A run's wall time is dominated by its steps; the adaptive method's steps cost more in phases 2 and 3.
On a machine shared with other jobs, timing two whole runs one after the other mostly measures the
other jobs, so this script times the phases *interleaved* (rounds of a few steps of each variant, in
turn) from the same trained backbone state, and reports medians. The predicted run-time ratio is

    (f1 * t_backbone + f2 * t_phase2 + f3 * t_phase3) / t_backbone    (+ the one-off skip check)

with the phase fractions f of the adaptive method's config.

    python benchmarks/bench_adaptive_overhead.py --backbone neus --checkpoint RUN --scene SCENE [--scene SCENE16]
        [--fused-per-ray 2 4]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import torch

from va_plugin.adaptive.field import BRANCHES, FUSION, backbone_state_in_wrapper
from va_plugin.adaptive.phases import view_residuals
from va_plugin.config import apply_override
from va_plugin.engine.trainer import load_checkpoint
from va_plugin.registry import get_method


PHASE_OVERRIDES = {BRANCHES: ("pipeline.model.field.pretrain_fraction=0", "pipeline.model.field.branch_fraction=1"),
                   FUSION: ("pipeline.model.field.pretrain_fraction=0", "pipeline.model.field.branch_fraction=0")}
"""A run that is in that phase from its first step (its phase callback sets it, and the shared field's
learning-rate factor with it); no consistency check and no pictures."""
ADAPTIVE_OVERRIDES = ("pipeline.model.field.skip_consistent_scenes=false", "pipeline.model.field.diagnostics_scale=0")


def make_trainer(method: str, scene: Path, state: dict, out: Path, overrides=()):
    """A trainer of ``method`` on ``scene`` starting from a trained backbone's model ``state``."""
    config = get_method(method).make_config()
    config.pipeline.datamanager.dataparser.data = Path(scene)
    config.output_dir, config.progress, config.checkpoint_every = out, False, 10 ** 9
    config.max_steps, config.schedule_steps = 10 ** 6, 0  # the schedules as before: over the whole budget
    for item in overrides:
        apply_override(config, item)
    trainer = config.setup()
    model_state = backbone_state_in_wrapper(state["model"]) if method.startswith("va-") else state["model"]
    target = trainer.model.state_dict()
    missing = [k for k in model_state if k not in target]
    if missing:
        raise SystemExit(f"checkpoint does not fit {method}: {missing[:3]} ...")
    target.update(model_state)
    trainer.model.load_state_dict(target)
    return trainer


def one_step(trainer) -> float:
    """Seconds of one training step with its callbacks."""
    return trainer.run_step()[1]


def measure(scene: Path, backbone: str, state: dict, out: Path, rounds: int, steps: int,
            fused_per_ray=(), adaptive_set=()) -> dict:
    """Median step times of the backbone, phase 2 and phase 3 (with the config's fused_samples_per_ray,
    and as ``phase3-kK`` with each K of ``fused_per_ray``), interleaved from the same state; ``adaptive_set``
    holds ``PATH=VALUE`` overrides of the adaptive variants (e.g. a smaller branch)."""
    adaptive = f"va-{backbone}"
    trainers = {backbone: make_trainer(backbone, scene, state, out / backbone)}
    variants = [("phase2", BRANCHES, ()), ("phase3", FUSION, ())]
    variants += [(f"phase3-k{k}", FUSION, (f"pipeline.model.field.fused_samples_per_ray={k}",)) for k in fused_per_ray]
    for name, phase, overrides in variants:
        trainers[name] = make_trainer(adaptive, scene, state, out / name,
                                      (*ADAPTIVE_OVERRIDES, *PHASE_OVERRIDES[phase], *adaptive_set, *overrides))
    times = {name: [] for name in trainers}
    shares = {name: [] for name in trainers if name.startswith("phase3")}
    for r in range(rounds + 1):
        for name, trainer in trainers.items():
            for _ in range(steps):
                elapsed = one_step(trainer)
                if r > 0:  # the first round warms up
                    times[name].append(elapsed)
                    if name in shares:
                        field = trainer.model.field
                        shares[name].append((field.adaptive_share, field.fused_share))
    start = time.perf_counter()
    view_residuals(trainers["phase2"].pipeline)
    check = time.perf_counter() - start
    adaptive_config = get_method(adaptive).make_config()
    for item in adaptive_set:
        apply_override(adaptive_config, item)
    field_cfg = adaptive_config.pipeline.model.field  # the method's phase fractions
    medians = {name: statistics.median(v) for name, v in times.items()}
    f1, f2 = field_cfg.pretrain_fraction, field_cfg.branch_fraction
    f3 = 1.0 - f1 - f2
    base = medians[backbone]
    return {
        "scene": str(scene), "adaptive_set": list(adaptive_set), "views": trainers[backbone].pipeline.datamanager.num_train_views,
        "median_step_s": {k: round(v, 4) for k, v in medians.items()},
        "ratio_phase2": round(medians["phase2"] / base, 3),
        **{f"ratio_{name}": round(medians[name] / base, 3) for name in shares},
        "adaptive_share_median": {name: round(statistics.median(a for a, _ in v), 4) for name, v in shares.items()},
        "fused_share_median": {name: round(statistics.median(f for _, f in v), 4) for name, v in shares.items()},
        "skip_check_s": round(check, 2),
        **{("predicted_run_ratio" if name == "phase3" else f"predicted_run_ratio_{name}"):
           round((f1 * base + f2 * medians["phase2"] + f3 * medians[name]) / base, 3) for name in shares},
        "samples": {k: len(v) for k, v in times.items()},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--backbone", default="neus", choices=["neus", "ngp"])
    parser.add_argument("--checkpoint", type=Path, required=True, help="a trained run of the backbone")
    parser.add_argument("--scene", type=Path, action="append", required=True, help="scene folder(s)")
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--steps", type=int, default=4, help="steps of each variant per round")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--fused-per-ray", type=int, nargs="*", default=[],
                        help="also time phase 3 with pipeline.model.field.fused_samples_per_ray=K for each K")
    parser.add_argument("--adaptive-set", action="append", default=[], metavar="PATH=VALUE",
                        help="config override of the adaptive variants (repeatable), e.g. "
                             "pipeline.model.field.branch_width=64")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/adaptive_overhead.json"))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    state = load_checkpoint(args.checkpoint)
    scratch = Path("/tmp/va-bench-overhead")
    results = [measure(scene, args.backbone, state, scratch, args.rounds, args.steps, args.fused_per_ray,
                       args.adaptive_set) for scene in args.scene]
    record = {"backbone": args.backbone, "checkpoint": str(args.checkpoint), "threads": args.threads,
              "machine": f"{platform.machine()}, {torch.get_num_threads()} threads, torch {torch.__version__}",
              "date": time.strftime("%Y-%m-%d"), "results": results}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=2))
    print(json.dumps(record, indent=2))


if __name__ == "__main__":
    main()
