"""The command line of the benchmark scripts: the flags every experiment shares (preset, scenes, level,
views, backbones, budget, jobs, resume), parsed and handed to the harness of :mod:`va_plugin.bench.experiment`
with one ``error: ...`` line and exit 2 on bad input, 130 on Ctrl-C.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from va_plugin.bench.catalog import DEFAULT_GSO_ROOT
from va_plugin.bench.experiment import Experiment, run_experiment
from va_plugin.bench.presets import BACKBONES, PRESETS
from va_plugin.cli.common import ArgumentParser, friendly_errors


def build_parser(experiment: Experiment) -> argparse.ArgumentParser:
    parser = ArgumentParser(description=experiment.description,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", default="quick", choices=sorted(PRESETS),
                        help="; ".join(f"{p.name}: {p.description}" for p in PRESETS.values()))
    parser.add_argument("--out", type=Path, default=None,
                        help=f"results folder (default outputs/bench/{experiment.name}-PRESET); scenes are "
                             "cached in OUT/scenes, runs go to OUT/runs")
    parser.add_argument("--data-root", type=Path, default=DEFAULT_GSO_ROOT,
                        help="folder of the Google Scanned Objects (default ../shared/data/gso)")
    parser.add_argument("--scenes", default=None,
                        help="comma-separated: NAME (procedural), gso:NAME, mesh:PATH, or the groups "
                             "procedural and gso (default: the preset's)")
    parser.set_defaults(level=None, views=None)  # the flags of the settings the experiment fixes are left out
    if "level" not in experiment.fixed:
        parser.add_argument("--level", type=int, default=None,
                            help="inconsistency level 0-3 (default: the preset's, 2)")
    if "views" not in experiment.fixed:
        parser.add_argument("--views", type=int, default=None, help="input views 4, 8, 12 or 16 (default 4)")
    parser.add_argument("--backbones", default=experiment.default_backbones,
                        help=f"comma-separated, of {', '.join(BACKBONES)} (default {experiment.default_backbones})")
    parser.add_argument("--steps", type=int, default=None, help="step budget of every run (default: the preset's)")
    parser.add_argument("--seed", type=int, default=42, help="seed of the scenes' inconsistency and of training")
    parser.add_argument("--force-adaptive", action="store_true",
                        help="run the adaptive phases even on scenes whose inputs look consistent "
                             "(pipeline.model.field.skip_consistent_scenes=false)")
    parser.add_argument("--adaptive-set", action="append", default=[], metavar="PATH=VALUE",
                        help="config override for the view-adaptive rows only, as va-train's --set (repeatable; "
                             "e.g. pipeline.model.field.shared_lr_scale=1.0): a variant against the same "
                             "original rows")
    parser.add_argument("--device", default="auto", help="auto, cpu or cuda[:N]")
    parser.add_argument("--threads", type=int, default=0,
                        help="torch CPU threads (of each row; 0: torch's default, with --jobs N the CPU count / N)")
    parser.add_argument("--jobs", type=int, default=1,
                        help="rows trained and evaluated at the same time, each in its own process (default 1: "
                             "one after the other, in this process)")
    parser.add_argument("--resume", action="store_true",
                        help="skip the rows OUT already holds (same settings); continue an interrupted row")
    if experiment.add_arguments is not None:
        experiment.add_arguments(parser)
    return parser


def main(experiment: Experiment, argv: list[str] | None = None, script: str | None = None) -> int:
    """Parse the flags and run the experiment (``error: ...`` and exit 2 on bad input, 130 on Ctrl-C)."""
    arguments = sys.argv[1:] if argv is None else list(argv)
    command = " ".join(["python", script or f"benchmarks/run_{experiment.name}.py",
                        *(shlex.quote(a) for a in arguments)])

    @friendly_errors
    def entry() -> int:
        args = build_parser(experiment).parse_args(arguments)
        return run_experiment(experiment, args, command)

    return entry()
