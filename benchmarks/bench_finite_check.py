"""The training guard's finite-value test: ``aminmax`` per tensor against ``isfinite(t).all()``, in ngp steps.

    python benchmarks/bench_finite_check.py [--scene DIR] [--warmup 60] [--rounds 6] [--steps 8] [--threads 1]

Trains ``ngp`` on a scene (default: the embedded default scene) for ``--warmup`` steps, then alternates
``--rounds`` rounds of ``--steps`` steps with each implementation of ``va_plugin.engine.health.all_finite``
in the same process, and prints the median step time of each (interleaving cancels drifts in load).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch

import va_plugin.engine.health as health
from va_plugin.cli.common import cache_dir
from va_plugin.registry import get_method


def reference(tensors) -> bool:
    return all(t is None or bool(torch.isfinite(t).all()) for t in tensors)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, default=cache_dir() / "default-scene-256")
    parser.add_argument("--warmup", type=int, default=60)
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--steps", type=int, default=8)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path("/tmp/va-bench-finite-check"))
    args = parser.parse_args(argv)
    if not args.scene.is_dir():
        raise SystemExit(f"error: no scene at {args.scene} (run va-demo once, or pass --scene)")
    torch.set_num_threads(args.threads)
    config = get_method("ngp").make_config()
    config.pipeline.datamanager.dataparser.data = args.scene
    config.output_dir, config.progress = args.out, False
    config.max_steps, config.checkpoint_every = 10 ** 6, 10 ** 9
    trainer = config.setup()
    variants = {"isfinite().all()": reference, "aminmax": health.all_finite}

    def steps(n):
        times = []
        for _ in range(n):
            start = time.perf_counter()
            trainer.run_step()
            times.append(time.perf_counter() - start)
        return times

    steps(args.warmup)
    times = {name: [] for name in variants}
    for _ in range(args.rounds):
        for name, check in variants.items():
            health.all_finite = check
            times[name] += steps(args.steps)
    for name, values in times.items():
        print(f"{name}: median step {1000 * statistics.median(values):.1f} ms over {len(values)} steps")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
