"""Do two versions of the code train the same? Seeded short runs of every method and preset, losses kept.

Usage:
    python benchmarks/same_losses.py record FILE [--steps N]
    python benchmarks/same_losses.py compare FILE [--steps N]

``record`` trains every registered method with each of its presets (and the view-adaptive methods once
more with their adaptive phases forced, so the branches and the attention train too) for N steps on a
small procedural scene, one torch thread, and writes every logged loss to FILE as JSON. ``compare`` trains
the same runs with the code as it is now and says, run by run, whether each logged value is bit for bit
the one in FILE; exit 0 when all are, 1 when not. Use it around a change that must not change training
(a refactor, a removed option that was off). The runs are shrunk (fewer rays and samples, the schedules
squeezed into the N steps so every phase, anneal and floor is reached), not the defaults' figures.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import torch

SHRINK = {"n_samples": 4, "n_importance": 4, "crossings_samples": 4}
"""Model options divided by these factors (a preset's differences survive the shrink)."""
LOGGED = ("loss", "psnr", "inv_s")


def runs():
    """(name, method, preset, extra overrides) of every run: each method x preset, plus forced phases."""
    from va_plugin.registry import discover_methods

    for method, spec in sorted(discover_methods().items()):
        for preset in ["default", *sorted(spec.presets)]:
            yield f"{method}/{preset}", method, preset, {}
        if method.startswith("va-"):
            yield f"{method}/default+phases", method, "default", {
                "pipeline.model.field.skip_consistent_scenes": "false"}


def train_losses(method: str, preset: str, extra: dict, scene: Path, steps: int) -> list:
    from va_plugin.config import apply_override
    from va_plugin.registry import get_method

    config = get_method(method).make_config(preset)
    config.method_name = method
    config.pipeline.datamanager.dataparser.data = scene
    config.max_steps = steps
    config.schedule_steps = steps
    config.log_every = 1
    config.checkpoint_every = steps
    config.progress = False
    config.device = "cpu"
    model = config.pipeline.model
    config.pipeline.datamanager.rays_per_batch //= 8
    for name, factor in SHRINK.items():
        if hasattr(model, name):
            setattr(model, name, max(1, getattr(model, name) // factor))
    for key, value in extra.items():
        apply_override(config, f"{key}={value}")
    with tempfile.TemporaryDirectory() as out:
        config.output_dir = Path(out)
        config.setup().train()
        lines = [json.loads(x) for x in (Path(out) / "metrics.jsonl").read_text().splitlines() if x.strip()]
    return [{k: r[k] for k in ("step", *LOGGED) if k in r} for r in lines if "loss" in r]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("mode", choices=("record", "compare"))
    parser.add_argument("file", type=Path)
    parser.add_argument("--steps", type=int, default=24)
    args = parser.parse_args()
    if args.mode == "compare" and not args.file.is_file():
        sys.exit(f"error: {args.file} does not exist; record it first with the code to compare against")
    torch.set_num_threads(1)
    from va_plugin.bench.scenes.builder import build_procedural_scene

    with tempfile.TemporaryDirectory() as tmp:
        scene = build_procedural_scene(Path(tmp), "mug", n_views=4, resolution=24)
        got = {}
        for name, method, preset, extra in runs():
            got[name] = train_losses(method, preset, extra, scene, args.steps)
            print(f"{name}: {len(got[name])} steps, final loss {got[name][-1]['loss']!r}", flush=True)
    if args.mode == "record":
        args.file.write_text(json.dumps({"steps": args.steps, "runs": got}, indent=1))
        print(f"recorded {len(got)} runs in {args.file}")
        return 0
    reference = json.loads(args.file.read_text())
    if reference["steps"] != args.steps:
        sys.exit(f"error: {args.file} was recorded with --steps {reference['steps']}")
    differ = 0
    for name in sorted(set(reference["runs"]) | set(got)):
        old, new = reference["runs"].get(name), got.get(name)
        if old is None or new is None:
            print(f"{name}: only in the {'new code' if old is None else 'recording'}")
            differ += 1
        elif old != new:
            first = next((o, n) for o, n in zip(old, new) if o != n) if len(old) == len(new) else (old, new)
            print(f"{name}: DIFFERS, first at {first[0]} against {first[1]}")
            differ += 1
        else:
            print(f"{name}: same bits ({len(new)} steps)")
    print("all runs the same bit for bit" if not differ else f"{differ} run(s) differ")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
