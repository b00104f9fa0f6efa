"""What the consistent-scene check costs, and whether its foreground sampling changes its answer.

At the end of phase 1 a view-adaptive run renders some pixels of every training view with the shared
field and compares their foreground PSNR across views (``va_plugin.adaptive.phases.view_residuals``).
This script loads trained runs and times that check two ways, interleaved: pixels on an even stride over
the whole image (16384 over all views; the check before 2026-11-24) and pixels spread evenly over each
view's foreground mask (4096 over all views; the default since), with the per-view foreground PSNRs
each way and the spread the test thresholds.

    python benchmarks/bench_consistency_check.py RUN [RUN ...] [--rounds 3] [--threads 1] [--out FILE]
"""

from __future__ import annotations

import os
import platform
import statistics
import time
from pathlib import Path

import torch

from va_plugin.bench.store import measure_run_folders
from va_plugin.cli.common import friendly_errors
from va_plugin.adaptive.phases import view_residuals
from va_plugin.cli.run import load_run
from va_plugin.errors import ConfigError

WAYS = {"stride": dict(foreground_pixels=0), "foreground": dict()}


def spread(residuals) -> float:
    values = [r["psnr_foreground"] for r in residuals]
    return max(values) - min(values)


def measure(run: Path, rounds: int) -> dict:
    pipeline, state = load_run(run, "cpu")
    if pipeline.datamanager.masks is None:
        raise ConfigError(f"{run}: its data has no foreground masks; the two ways are the same there")
    seconds = {way: [] for way in WAYS}
    residuals = {}
    for _ in range(rounds):
        for way, options in WAYS.items():
            start = time.perf_counter()
            residuals[way] = view_residuals(pipeline, **options)
            seconds[way].append(time.perf_counter() - start)
    result = {"run": str(run), "method": state.get("method_name"), "step": int(state["step"]),
              "views": pipeline.datamanager.num_train_views}
    for way in WAYS:
        result[way] = {"median_s": round(statistics.median(seconds[way]), 3),
                       "seconds": [round(s, 3) for s in seconds[way]],
                       "pixels": sum(r["pixels"] for r in residuals[way]),
                       "psnr_foreground": [round(r["psnr_foreground"], 3) for r in residuals[way]],
                       "spread_db": round(spread(residuals[way]), 3)}
    result["speedup"] = round(result["stride"]["median_s"] / max(result["foreground"]["median_s"], 1e-9), 2)
    return result


def _record(args) -> dict:
    return {"date": time.strftime("%Y-%m-%d %H:%M"), "threads": args.threads, "cpus": os.cpu_count(),
            "platform": platform.platform(), "torch": torch.__version__,
            "results": [measure(run, args.rounds) for run in args.runs]}


@friendly_errors
def main() -> int:
    return measure_run_folders(__doc__, "run folders (any method; the check uses the shared field)",
                               lambda parser: parser.add_argument("--rounds", type=int, default=3), _record)


if __name__ == "__main__":
    raise SystemExit(main())
