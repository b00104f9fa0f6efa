"""The colour-cast measure of trained runs (issue 21's consistent-scene check): per-view colour gains
fitted on the shared surface (``va_plugin.adaptive.consistency.colour_cast``), their worst deviation from
view 0 and what the measure costs, one line per run, with the silhouette test's figure beside it.

    python benchmarks/bench_colour_cast.py RUN [RUN ...] [--resolution 64] [--out FILE.jsonl]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

from va_plugin.adaptive.consistency import colour_cast
from va_plugin.adaptive.phases import input_silhouette_support
from va_plugin.cli.common import friendly_errors
from va_plugin.cli.run import load_run
from va_plugin.export.texture import run_views


def measure(run: Path, resolution: int) -> dict:
    pipeline, state = load_run(run, "cpu")
    views = run_views(pipeline)
    cast = colour_cast(pipeline.model, views.cameras, views.images, views.masks, resolution=resolution)
    support = input_silhouette_support(pipeline.datamanager)
    return {"run": str(run), "step": int(state["step"]), **cast.as_dict(),
            "silhouette_unsupported": None if support is None else round(support.worst, 5)}


@friendly_errors
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+", help="run folders of va-train")
    parser.add_argument("--resolution", type=int, default=64, help="marching-cubes grid of the surface")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--out", type=Path, default=None, help="also append the lines to this JSON-lines file")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    for run in args.runs:
        record = measure(run, args.resolution)
        line = json.dumps(record)
        print(line, flush=True)
        if args.out is not None:
            with args.out.open("a") as f:
                f.write(line + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
