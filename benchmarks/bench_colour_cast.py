"""The colour-cast measure of trained runs (issue 21's consistent-scene check): per-view colour gains
fitted on the shared surface (``va_plugin.adaptive.consistency.colour_cast``), their worst deviation from
view 0 and what the measure costs, one line per run, with the silhouette test's figure beside it.

    python benchmarks/bench_colour_cast.py RUN [RUN ...] [--resolution 96] [--out FILE.jsonl]

With ``--train-to STEP`` the arguments are inputs instead (scene folders or generator outputs, as
``va-train --data`` takes them): each is trained with the ``neus`` default up to STEP of its schedule
(667 of 2000 is where ``va-neus`` decides), checkpointed into ``--runs-dir``, and then measured, with the
per-view residual spread of that state too.

    python benchmarks/bench_colour_cast.py --train-to 667 --runs-dir outputs/cast SCENE [SCENE ...]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

from va_plugin.adaptive.consistency import colour_cast
from va_plugin.adaptive.phases import (COLOUR_CAST_GRID, input_silhouette_support, residual_spread_db,
                                       view_residuals)
from va_plugin.cli.common import friendly_errors
from va_plugin.cli.run import load_run
from va_plugin.errors import ConfigError
from va_plugin.export.texture import run_views

MIN_RESOLUTION = 8


def measure(pipeline, step: int, resolution: int, with_residuals: bool = False) -> dict:
    views = run_views(pipeline)
    cast = colour_cast(pipeline.model, views.cameras, views.images, views.masks, resolution=resolution)
    support = input_silhouette_support(pipeline.datamanager)
    record = {"step": step, **cast.as_dict(),
              "silhouette_unsupported": None if support is None else round(support.worst, 5)}
    if with_residuals:
        record["residual_spread_db"] = round(residual_spread_db(view_residuals(pipeline)), 3)
    return record


def train_to(data: str, step: int, runs_dir: Path):
    """The ``neus`` default trained on ``data`` up to ``step`` of its schedule (not its end), checkpointed."""
    from va_plugin.cli.train import build_parser, make_config
    from va_plugin.registry import discover_methods

    methods = discover_methods()
    args = build_parser(methods).parse_args(["neus", "--data", data, "--output-dir", str(runs_dir / Path(data).stem)])
    config = make_config(args, methods)
    config.progress = False
    if not 0 < step <= config.max_steps:
        raise ConfigError(f"--train-to must be in 1..{config.max_steps} (the default schedule), got {step}")
    trainer = config.setup()
    trainer._write_config()
    while trainer.step < step:
        trainer.run_step()
    trainer.save_checkpoint()
    return trainer.pipeline


@friendly_errors
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("inputs", nargs="+", help="run folders of va-train (with --train-to: inputs to train on)")
    parser.add_argument("--resolution", type=int, default=COLOUR_CAST_GRID,
                        help="marching-cubes grid of the surface (the consistency decision uses "
                        f"{COLOUR_CAST_GRID})")
    parser.add_argument("--train-to", type=int, default=None, help="train each input to this step first")
    parser.add_argument("--runs-dir", type=Path, default=Path("outputs/colour_cast"),
                        help="with --train-to: where the runs go")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--out", type=Path, default=None, help="also append the lines to this JSON-lines file")
    args = parser.parse_args(argv)
    if args.resolution < MIN_RESOLUTION:
        raise ConfigError(f"--resolution must be at least {MIN_RESOLUTION}, got {args.resolution}")
    torch.set_num_threads(args.threads)
    for item in args.inputs:
        if args.train_to is not None:
            pipeline = train_to(item, args.train_to, args.runs_dir)
            record = {"input": item, **measure(pipeline, args.train_to, args.resolution, with_residuals=True)}
        else:
            pipeline, state = load_run(Path(item), "cpu")
            record = {"run": item, **measure(pipeline, int(state["step"]), args.resolution)}
        line = json.dumps(record)
        print(line, flush=True)
        if args.out is not None:
            with args.out.open("a") as f:
                f.write(line + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
