"""Which canonical feature renders novel views better, on the same trained view-adaptive weights.

A view-adaptive run renders novel views with a canonical feature: the mean over views of f_fused,i
(``canonical=mean``) or f_shared (``canonical=shared``, the default). Both are read off the same trained
weights, so one run scores both, and the difference is the canonical feature alone.

    python benchmarks/bench_canonical.py RUN [RUN ...] [--image-scale 0.5] [--max-views 4] [--threads 1]

Writes a JSON of the held-out PSNR, SSIM and LPIPS per run and canonical feature (stdout, or --out).
"""

from __future__ import annotations

import time
from pathlib import Path

import torch

from va_plugin.bench.store import measure_run_folders
from va_plugin.cli.common import friendly_errors
from va_plugin.cli.run import load_run
from va_plugin.errors import ConfigError
from va_plugin.eval.evaluate import image_metrics

CANONICALS = ("mean", "shared")


def score(run: Path, image_scale: float, max_views: int) -> dict:
    pipeline, state = load_run(run, "cpu")
    field = pipeline.model.field
    if not hasattr(field, "config") or not hasattr(field.config, "canonical"):
        raise ConfigError(f"{run}: not a view-adaptive run")
    result = {"run": str(run), "method": state.get("method_name"), "step": int(state["step"]),
              "phase": int(field.current_phase)}
    for canonical in CANONICALS:
        field.config.canonical = canonical
        metrics = image_metrics(pipeline, image_scale, max_views, progress=False)
        result[canonical] = {k: round(float(metrics[k]), 4) for k in ("psnr", "ssim", "lpips") if k in metrics}
    result["psnr_shared_minus_mean"] = round(result["shared"]["psnr"] - result["mean"]["psnr"], 3)
    return result


def _options(parser) -> None:
    parser.add_argument("--image-scale", type=float, default=0.5)
    parser.add_argument("--max-views", type=int, default=4)


def _record(args) -> dict:
    return {"date": time.strftime("%Y-%m-%d"), "image_scale": args.image_scale, "max_views": args.max_views,
            "results": [score(run, args.image_scale, args.max_views) for run in args.runs]}


@friendly_errors
def main() -> int:
    return measure_run_folders(__doc__, "run folders of va-neus / va-ngp", _options, _record)


if __name__ == "__main__":
    raise SystemExit(main())
