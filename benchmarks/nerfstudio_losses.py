"""Does ``ns-train`` train as ``va-train`` does? The first steps' loss terms of one method under both
trainers, at the method's defaults, on one input (run with the Python of ``.venv-ns/``).

Usage:
    .venv-ns/bin/python benchmarks/nerfstudio_losses.py INPUT [--method va-neus] [--steps 5] [--squeeze]
        [--out FILE.json]

``--squeeze`` ends the schedules at ``--steps`` so that the view-adaptive phases switch within the run.
The diagnostics pictures are off in both runs (they come after the last step and take minutes).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import torch

from va_plugin.config import apply_override
from va_plugin.data.dataparsers import resolve_dataparser
from va_plugin.nerfstudio.compare import largest_difference, ns_train_losses, va_train_losses
from va_plugin.nerfstudio.methods import NERFSTUDIO_NAMES, nerfstudio_config
from va_plugin.registry import builtin_methods


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("input", type=Path)
    parser.add_argument("--method", default="va-neus", choices=sorted(NERFSTUDIO_NAMES))
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument("--squeeze", action="store_true", help="the schedules end at --steps")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    torch.set_num_threads(2)
    ours_name = NERFSTUDIO_NAMES[args.method]
    with tempfile.TemporaryDirectory() as tmp:
        ours = builtin_methods()[ours_name].make_config()
        ours.pipeline.datamanager.dataparser = resolve_dataparser(args.input.resolve())
        ours.output_dir, ours.max_steps, ours.progress, ours.device = Path(tmp) / "ours", args.steps, False, "cpu"
        if args.squeeze:
            ours.schedule_steps = args.steps
        if hasattr(ours.pipeline.model.field, "diagnostics_scale"):
            apply_override(ours, "pipeline.model.field.diagnostics_scale=0")
        theirs = nerfstudio_config(args.method, ours_name)
        theirs.pipeline.schedule_steps = ours.schedule_steps
        theirs.pipeline.model.va = ours.pipeline.model
        theirs.pipeline.datamanager.dataparser.data = args.input.resolve()
        theirs.output_dir, theirs.timestamp, theirs.vis = Path(tmp) / "ns", "run", "tensorboard"
        theirs.machine.device_type = "cpu"
        expected = va_train_losses(ours, args.steps)
        got = ns_train_losses(theirs, args.steps)
    result = {"method": args.method, "input": str(args.input), "steps": args.steps, "squeeze": args.squeeze,
              "va_train": expected, "ns_train": got, "largest_relative_difference": largest_difference(expected, got)}
    for step, (a, b) in enumerate(zip(expected, got, strict=False)):
        print(f"step {step}: " + ", ".join(f"{k} {a[k]:.7g} / {b.get(k, float('nan')):.7g}" for k in a))
    print(f"largest relative difference: {result['largest_relative_difference']:.3g}")
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1))
    return 0 if result["largest_relative_difference"] <= 1e-5 else 1


if __name__ == "__main__":
    sys.exit(main())
