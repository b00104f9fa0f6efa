"""Inconsistency maps: one render pass per view (own and canonical colour together) against two renders.

    python benchmarks/bench_diagnostics_pass.py RUN [--view 1] [--scale 0.25] [--repeats 2] [--threads 1]

RUN is a trained view-adaptive run folder. Prints the seconds of each way and the largest difference
between their images (0 expected).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from va_plugin.cli.run import load_run
from va_plugin.export.render import render_view


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--view", type=int, default=1)
    parser.add_argument("--scale", type=float, default=0.25)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    pipeline, _ = load_run(args.run)
    model = pipeline.model
    if not hasattr(model.field, "also_canonical"):
        raise SystemExit(f"error: {args.run} is not a view-adaptive run")
    cameras = pipeline.datamanager.cameras.scaled(args.scale)
    for _ in range(args.repeats):
        start = time.perf_counter()
        own, canonical = render_view(model, cameras, args.view, as_view=args.view), render_view(model, cameras, args.view)
        two = time.perf_counter() - start
        model.field.also_canonical = True
        start = time.perf_counter()
        own1, canonical1 = render_view(model, cameras, args.view, as_view=args.view, keys=("rgb", "rgb_canonical"))
        one = time.perf_counter() - start
        model.field.also_canonical = False
        diff = max(float(np.abs(own - own1).max()), float(np.abs(canonical - canonical1).max()))
        print(f"two renders {two:.2f} s, one pass {one:.2f} s, largest difference {diff:.1e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
