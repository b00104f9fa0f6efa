"""``va-train METHOD``: train a registered method on a scene."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from va_plugin.api import VIEW_COUNTS, TrainingInterrupted, build_config, export_mesh, train
from va_plugin.bench.scenes import default_scene
from va_plugin.cli.common import (
    EXIT_INTERRUPTED,
    ArgumentParser,
    add_quiet_option,
    check_output_dir,
    friendly_errors,
    path_argument,
)
from va_plugin.config import format_options
from va_plugin.data.dataparsers import FORMATS
from va_plugin.engine.metrics_log import training_records
from va_plugin.registry import discover_methods


def build_parser(methods) -> argparse.ArgumentParser:
    lines = []
    for name, spec in methods.items():
        lines.append(f"  {name:<14} {spec.description}")
        lines.extend(f"  {'':<14}   --preset {preset}: {p.description}" for preset, p in sorted(spec.presets.items()))
    listing = "\n".join(lines)
    parser = ArgumentParser(
        prog="va-train", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Train a reconstruction method on a scene (neus is the recommended method; va-recon does "
                    "training, textured mesh and turntable in one command).\n\nmethods and their presets:\n" + listing,
        epilog="Without --data, the embedded default scene (a procedural object on the SyncDreamer rig) "
               "is generated and used. Defaults are the method's; --help-config lists every --set key.")
    parser.add_argument("method", help="one of the methods listed above")
    parser.add_argument("--data", type=path_argument, default=None, help="scene folder or generator output")
    add_object_options(parser)
    parser.add_argument("--masks", type=path_argument, default=None,
                        help="generator inputs: mask folder (one image per view) or one mask image in the "
                             "input's layout, instead of the color key")
    parser.add_argument("--output-dir", type=path_argument, default=None, help="run folder (default outputs/METHOD)")
    parser.add_argument("--resume", action="store_true", help="continue from the run folder's newest checkpoint")
    parser.add_argument("--overwrite", action="store_true",
                        help="write into the run folder even when it holds other files (an earlier run there "
                             "starts again)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_quiet_option(parser)
    parser.add_argument("--export-mesh", action="store_true", help="write mesh.ply into the run folder at the end")
    parser.add_argument("--default-scene-resolution", type=int, default=256,
                        help="image size of the embedded default scene")
    parser.add_argument("--help-config", action="store_true",
                        help="list every --set key of the method (with --preset, --data and --set applied) with "
                             "its value and description, then exit")
    return parser


VIEWS_HELP = "SyncDreamer: training views of its 16, uniform in azimuth: 4, 8, 12, 16 or all"


def parse_views(text: str):
    """``--views``: one of :data:`~va_plugin.api.VIEW_COUNTS`, or ``all`` (every view the input has)."""
    if text.strip().lower() == "all":
        return "all"
    if text.strip().isdigit() and int(text) in VIEW_COUNTS:
        return int(text)
    raise argparse.ArgumentTypeError(f"{text!r} is not one of 4, 8, 12, 16 or all")


def add_object_options(parser: argparse.ArgumentParser) -> None:
    """The options that make sense for every object of a batch (va-batch takes them too): how to read the
    input and what to train."""
    parser.add_argument("--data-format", default="auto", metavar="{auto," + ",".join(FORMATS) + "}",
                        help="input format (default auto: detected from the input)")
    parser.add_argument("--views", type=parse_views, default=None, help=VIEWS_HELP + " (default: all)")
    add_rig_options(parser)
    parser.add_argument("--preset", default=None, help="a named variant of the method (see its presets)")
    parser.add_argument("--steps", type=int, default=None,
                        help="step budget (overrides the method's); steps past the method's schedule_steps "
                             "continue at the schedules' final values (--set schedule_steps=0 stretches them)")
    parser.add_argument("--seed", type=int, default=None, help="random seed (default 42)")
    parser.add_argument("--device", default=None, help="auto, cpu or cuda[:N] (default auto)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="PATH=VALUE",
                        help="override any config value, e.g. pipeline.model.eikonal_weight=0.05")


def add_rig_options(parser: argparse.ArgumentParser) -> None:
    """``--elevation``, ``--fov`` and ``--rig``: the cameras of a generator's output."""
    parser.add_argument("--elevation", type=float, default=None,
                        help="camera elevation in degrees of every view: SyncDreamer (default 30), SV3D (default "
                             "10, the elevation sv3d_p was given), 4-view rigs and other rigs with one elevation")
    parser.add_argument("--fov", type=float, default=None,
                        help="field of view in degrees across a view, for perspective rigs (SV3D, Hunyuan3D, "
                             "4-view rigs, Wonder3D++ persp, a rig file)")
    parser.add_argument("--rig", default=None,
                        help="a rig file (.json or .yaml: layout, view order, azimuths, elevations, camera; see "
                             "docs/data.md) describing the input, a built-in rig's name, or for Zero123++ its "
                             "model version, v1.1 or v1.2 (default v1.2)")


OBJECT_OPTIONS = ("data_format", "views", "elevation", "fov", "rig", "preset", "steps", "seed", "device",
                  "overrides")
"""The :func:`add_object_options` flags, by their names in :func:`va_plugin.api.build_config`."""


def object_options(args: argparse.Namespace) -> dict:
    """The :func:`add_object_options` values of a parsed command line, as ``build_config`` keywords."""
    return {name: getattr(args, name) for name in OBJECT_OPTIONS}


def make_config(args: argparse.Namespace, resolve_data: bool = True):
    """The trainer config of a parsed ``va-train`` command line: without ``--data``, on the embedded default
    scene (``resolve_data=False``: the method's own dataparser config, without reading the input or
    building the default scene)."""
    data = args.data
    if data is None and resolve_data:
        data = default_scene(args.default_scene_resolution)
    return build_config(args.method, data if resolve_data else None, out=args.output_dir, masks=args.masks,
                        progress=not (args.no_progress or args.quiet), **object_options(args))


def training_summary(method: str, run_dir: Path) -> str:
    """``trained METHOD for N steps in S s (loss .., psnr .., inv_s ..)``, from the run's last training record;
    figures the record lacks are left out (and the brackets with them)."""
    record = (training_records(run_dir) or [{}])[-1]
    figures = [f"{k} {record[k]:.4g}" for k in ("loss", "psnr", "inv_s")
               if isinstance(record.get(k), (int, float)) and not isinstance(record.get(k), bool)]
    steps, seconds = int(record.get("step", 0)), float(record.get("train_seconds", 0.0))
    text = f"trained {method} for {steps} step{'' if steps == 1 else 's'} in {seconds:.1f} s"
    return text + (f" ({', '.join(figures)})" if figures else "")


def say(line: str) -> None:
    print(line, file=sys.stderr)


@friendly_errors
def main(argv: list[str] | None = None) -> int:
    methods = discover_methods()
    args = build_parser(methods).parse_args(argv)
    if args.help_config:
        print(f"--set keys of {args.method} (preset {args.preset or 'default'}): key = value, then what it does")
        print(format_options(make_config(args, resolve_data=False)), end="")
        return 0
    config = make_config(args)
    run_dir = Path(config.output_dir)
    check_output_dir(run_dir, "--output-dir")
    try:
        train(config, resume=args.resume, overwrite=args.overwrite, on_message=None if args.quiet else say)
    except TrainingInterrupted as interrupt:
        print(f"{interrupt}; continue with --resume", file=sys.stderr)
        return EXIT_INTERRUPTED
    print(f"{training_summary(config.method_name, run_dir)}; run folder {run_dir}")
    if args.export_mesh:
        path = export_mesh(run_dir, texture=False, device=args.device).path
        print(f"mesh written to {path}")
    if not args.quiet:
        print(f"next: va-export mesh --load-dir {run_dir} --texture   (textured mesh: {run_dir / 'mesh.glb'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
