"""Milliseconds per training step of several method variants, interleaved on one scene.

Each variant's trainer is built once; then the variants take one step each in turn, ``--repeats`` times,
so that all of them see the same machine load; the first round is discarded and the median is printed.
By default the trainers start at their last step, so every schedule is at its end (all hash-grid levels
open, a view-adaptive method in its last phase: the most expensive step of a run). The state is untrained,
so the SDF band keeps more samples than a trained run's would; with ``--from-run RUN`` every trainer starts
from that finished run's last checkpoint instead (the variants must then share its parameters: options
that change only losses or sampling), which times the late steps of a real run.

    python benchmarks/bench_step_cost.py --data SCENE [--variants neus neus:mlp "neus+pipeline.model.n_importance=16"]
        [--repeats 6] [--threads 1] [--at-start | --from-run RUN]

A variant is METHOD[:PRESET] followed by any number of ``+PATH=VALUE`` config overrides.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

import torch

from va_plugin.cli.common import friendly_errors
from va_plugin.config import apply_override
from va_plugin.engine.trainer import load_checkpoint
from va_plugin.errors import ConfigError
from va_plugin.registry import get_method


def build_trainer(variant: str, data: Path, run_dir: Path):
    head, *overrides = variant.split("+")
    method, _, preset = head.partition(":")
    config = get_method(method).make_config(preset or None)
    config.pipeline.datamanager.dataparser.data = data
    config.output_dir = run_dir
    config.progress = False
    for assignment in overrides:
        apply_override(config, assignment)
    return config.setup()


@friendly_errors
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="scene folder")
    parser.add_argument("--variants", nargs="+", default=["neus", "neus:mlp"])
    parser.add_argument("--repeats", type=int, default=6)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--at-start", action="store_true", help="time the first steps' state (schedules at step 0)")
    parser.add_argument("--from-run", type=Path, default=None,
                        help="a finished run folder of the same scene: every trainer starts from its last checkpoint")
    args = parser.parse_args(argv)
    if args.repeats < 2:
        raise ConfigError("--repeats must be at least 2 (the first round is discarded)")
    if args.at_start and args.from_run is not None:
        raise ConfigError("--at-start and --from-run exclude each other")
    checkpoint = load_checkpoint(args.from_run) if args.from_run is not None else None
    torch.set_num_threads(args.threads)
    with tempfile.TemporaryDirectory() as tmp:
        trainers = {v: build_trainer(v, args.data, Path(tmp) / str(i)) for i, v in enumerate(args.variants)}
        for trainer in trainers.values():
            if checkpoint is not None:
                trainer.load_state(checkpoint)
            if not args.at_start:  # the pipeline sets the schedules from trainer.step before each step
                trainer.step = trainer.config.max_steps - 1
        times = {v: [] for v in trainers}
        for _ in range(args.repeats):
            for variant, trainer in trainers.items():
                times[variant].append(trainer.run_step()[1])
    print(f"| variant | ms / step (median of {args.repeats - 1}, {args.threads} thread(s)) |\n|---|---|")
    for variant, values in times.items():
        print(f"| `{variant}` | {1000 * statistics.median(values[1:]):.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
