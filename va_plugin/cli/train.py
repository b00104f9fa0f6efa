"""``va-train METHOD``: train a registered method on a scene."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import List, Optional

from va_plugin.cli.common import EXIT_INTERRUPTED, cache_dir, check_output_dir, friendly_errors
from va_plugin.config import apply_override, format_options
from va_plugin.data.datamanager import MASK_PICTURE
from va_plugin.data.dataparsers import FORMATS, resolve_dataparser
from va_plugin.errors import ConfigError
from va_plugin.registry import discover_methods


def build_parser(methods) -> argparse.ArgumentParser:
    lines = []
    for name, spec in methods.items():
        lines.append(f"  {name:<14} {spec.description}")
        lines.extend(f"  {'':<14}   --preset {preset}: {p.description}" for preset, p in sorted(spec.presets.items()))
    listing = "\n".join(lines)
    parser = argparse.ArgumentParser(
        prog="va-train", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Train a reconstruction method on a scene (neus is the recommended method; va-recon does "
                    "training, textured mesh and turntable in one command).\n\nmethods and their presets:\n" + listing,
        epilog="Without --data, the embedded default scene (a procedural object on the SyncDreamer rig) "
               "is generated and used. Defaults are the method's; --help-config lists every --set key.")
    parser.add_argument("method", help="one of the methods listed above")
    parser.add_argument("--data", type=Path, default=None, help="scene folder or generator output")
    add_object_options(parser)
    parser.add_argument("--masks", type=Path, default=None,
                        help="generator inputs: mask folder (one image per view) or one mask image in the "
                             "input's layout, instead of the colour key")
    parser.add_argument("--output-dir", type=Path, default=None, help="run folder (default outputs/METHOD)")
    parser.add_argument("--resume", action="store_true", help="continue from the run folder's newest checkpoint")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--export-mesh", action="store_true", help="write mesh.ply into the run folder at the end")
    parser.add_argument("--default-scene-resolution", type=int, default=256,
                        help="image size of the embedded default scene")
    parser.add_argument("--help-config", action="store_true",
                        help="list every --set key of the method (with --preset, --data and --set applied) with "
                             "its value and description, then exit")
    return parser


VIEWS_HELP = "SyncDreamer: training views of its 16, uniform in azimuth: 4, 8, 12, 16 or all"
VIEW_COUNTS = (4, 8, 12, 16)


def parse_views(text: str):
    """``--views``: one of :data:`VIEW_COUNTS`, or ``all`` (every view the input has)."""
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
    parser.add_argument("--elevation", type=float, default=None,
                        help="SyncDreamer: camera elevation in degrees (default 30)")
    parser.add_argument("--rig", default=None, help="Zero123++: model version, v1.1 or v1.2 (default v1.2)")
    parser.add_argument("--preset", default=None, help="a named variant of the method (see its presets)")
    parser.add_argument("--steps", type=int, default=None,
                        help="step budget (overrides the method's); steps past the method's schedule_steps "
                             "continue at the schedules' final values (--set schedule_steps=0 stretches them)")
    parser.add_argument("--seed", type=int, default=None, help="random seed (default 42)")
    parser.add_argument("--device", default=None, help="auto, cpu or cuda[:N] (default auto)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="PATH=VALUE",
                        help="override any config value, e.g. pipeline.model.eikonal_weight=0.05")


# flag -> (dataparser option, the formats that have it)
GENERATOR_OPTIONS = {"views": ("num_views", "syncdreamer"), "elevation": ("elevation_deg", "syncdreamer"),
                     "rig": ("rig", "zero123pp"), "masks": ("masks", "syncdreamer, zero123pp and wonder3d")}


def apply_generator_options(parser_config, args: argparse.Namespace) -> None:
    """Copy the generator flags that were given onto the dataparser config, refusing ones it lacks."""
    for flag, (option, formats) in GENERATOR_OPTIONS.items():
        value = getattr(args, flag)
        if value is None:
            continue
        if value == "all":  # every view the input has: the generators' parsers train on all by default
            if hasattr(parser_config, option):
                setattr(parser_config, option, max(VIEW_COUNTS))
            continue
        if not hasattr(parser_config, option):
            raise ConfigError(f"--{flag} applies to {formats} inputs only")
        setattr(parser_config, option, value)


def make_config(args: argparse.Namespace, methods, resolve_data: bool = True):
    """The trainer config of a parsed command line (``resolve_data=False``: the method's own dataparser
    config, without reading the input or building the default scene)."""
    if args.method not in methods:
        raise ConfigError(f"unknown method {args.method!r}; known methods: {', '.join(methods)}")
    config = methods[args.method].make_config(args.preset)
    config.method_name = args.method
    data = args.data
    if data is None and resolve_data:
        from va_plugin.data.scenes.builder import ensure_default_scene

        data = ensure_default_scene(cache_dir() / f"default-scene-{args.default_scene_resolution}",
                                    resolution=args.default_scene_resolution)
    if data is not None:
        config.pipeline.datamanager.dataparser = resolve_dataparser(Path(data), args.data_format,
                                                                    config.pipeline.datamanager.dataparser)
        apply_generator_options(config.pipeline.datamanager.dataparser, args)
    config.output_dir = args.output_dir if args.output_dir is not None else Path("outputs") / args.method
    if args.steps is not None:
        if args.steps < 1:
            raise ConfigError(f"--steps must be at least 1, got {args.steps}")
        config.max_steps = args.steps
    if args.seed is not None:
        config.seed = args.seed
    if args.device is not None:
        config.device = args.device
    config.progress = not args.no_progress
    for assignment in args.overrides:
        apply_override(config, assignment)
    return config


def describe_inputs(trainer, run_dir: Path) -> None:
    """One line on stderr about generator inputs: format, views and where the masks came from."""
    meta = trainer.pipeline.datamanager.train.metadata
    if "mask_source" in meta:
        views = len(trainer.pipeline.datamanager.train)
        print(f"{meta['format']} input: {views} training views, masks from the {meta['mask_source']} "
              f"(check {run_dir / MASK_PICTURE})", file=sys.stderr)


@friendly_errors
def main(argv: Optional[List[str]] = None) -> int:
    methods = discover_methods()
    args = build_parser(methods).parse_args(argv)
    if args.help_config:
        print(f"--set keys of {args.method} (preset {args.preset or 'default'}): key = value, then what it does")
        print(format_options(make_config(args, methods, resolve_data=False)), end="")
        return 0
    config = make_config(args, methods)
    run_dir = Path(config.output_dir)
    check_output_dir(run_dir, "--output-dir")
    from va_plugin.engine.trainer import TrainingInterrupted, list_checkpoints, train_run

    if not args.resume and list_checkpoints(run_dir):
        raise ConfigError(f"{run_dir} already holds checkpoints; pass --resume to continue, "
                          "or choose another --output-dir")
    trainer = config.setup()
    describe_inputs(trainer, run_dir)
    try:
        record = train_run(config, resume=args.resume, trainer=trainer, on_resume=lambda step: print(
            f"resuming {config.method_name} from step {step}", file=sys.stderr)).record
    except TrainingInterrupted as interrupt:
        print(f"interrupted at step {interrupt.step}; saved {interrupt.checkpoint}; continue with --resume",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    summary = ", ".join(f"{k} {record[k]:.4g}" for k in ("loss", "psnr", "inv_s") if k in record)
    print(f"trained {config.method_name} for {trainer.step} steps in {trainer.train_seconds:.1f} s ({summary}); "
          f"run folder {run_dir}")
    health = trainer.guard.summary()
    if health:
        print(f"warning: {health}", file=sys.stderr)
    if args.export_mesh:
        from va_plugin.export.mesh import export_run_mesh

        path = export_run_mesh(trainer.pipeline, run_dir / "mesh.ply")
        print(f"mesh written to {path}")
    print(f"next: va-export mesh --load-dir {run_dir} --texture   (textured mesh: {run_dir / 'mesh.glb'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
