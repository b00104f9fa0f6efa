"""``va-train METHOD``: train a registered method on a scene."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import List, Optional

from va_plugin.cli.common import EXIT_INTERRUPTED, cache_dir, friendly_errors
from va_plugin.config import apply_override
from va_plugin.data.dataparsers import resolve_dataparser
from va_plugin.errors import ConfigError
from va_plugin.registry import discover_methods


def build_parser(methods) -> argparse.ArgumentParser:
    listing = "\n".join(f"  {name:<14} {spec.description}" for name, spec in methods.items())
    parser = argparse.ArgumentParser(
        prog="va-train", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Train a reconstruction method on a scene.\n\nmethods:\n" + listing,
        epilog="Without --data, the embedded default scene (a procedural object on the SyncDreamer rig) "
               "is generated and used.")
    parser.add_argument("method", help="one of the methods listed above")
    parser.add_argument("--data", type=Path, default=None, help="scene folder or generator output")
    parser.add_argument("--data-format", default="auto", help="input format (auto detects it)")
    parser.add_argument("--output-dir", type=Path, default=None, help="run folder (default outputs/METHOD)")
    parser.add_argument("--preset", default=None, help="a named variant of the method (see its presets)")
    parser.add_argument("--steps", type=int, default=None, help="step budget (overrides the method's)")
    parser.add_argument("--seed", type=int, default=None, help="random seed (default 42)")
    parser.add_argument("--device", default=None, help="auto, cpu or cuda[:N] (default auto)")
    parser.add_argument("--resume", action="store_true", help="continue from the run folder's newest checkpoint")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="PATH=VALUE",
                        help="override any config value, e.g. pipeline.model.eikonal_weight=0.05")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--export-mesh", action="store_true", help="write mesh.ply into the run folder at the end")
    parser.add_argument("--default-scene-resolution", type=int, default=256,
                        help="image size of the embedded default scene")
    return parser


def make_config(args: argparse.Namespace, methods):
    """The trainer config of a parsed command line."""
    if args.method not in methods:
        raise ConfigError(f"unknown method {args.method!r}; known methods: {', '.join(methods)}")
    config = methods[args.method].make_config(args.preset)
    config.method_name = args.method
    data = args.data
    if data is None:
        from va_plugin.data.scenes.builder import ensure_default_scene

        data = ensure_default_scene(cache_dir() / f"default-scene-{args.default_scene_resolution}",
                                    resolution=args.default_scene_resolution)
    config.pipeline.datamanager.dataparser = resolve_dataparser(Path(data), args.data_format,
                                                                config.pipeline.datamanager.dataparser)
    config.output_dir = args.output_dir if args.output_dir is not None else Path("outputs") / args.method
    if args.steps is not None:
        config.max_steps = args.steps
    if args.seed is not None:
        config.seed = args.seed
    if args.device is not None:
        config.device = args.device
    config.progress = not args.no_progress
    for assignment in args.overrides:
        apply_override(config, assignment)
    return config


@friendly_errors
def main(argv: Optional[List[str]] = None) -> int:
    methods = discover_methods()
    args = build_parser(methods).parse_args(argv)
    config = make_config(args, methods)
    run_dir = Path(config.output_dir)
    from va_plugin.engine.trainer import list_checkpoints

    if not args.resume and list_checkpoints(run_dir):
        raise ConfigError(f"{run_dir} already holds checkpoints; pass --resume to continue, "
                          "or choose another --output-dir")
    trainer = config.setup()
    if args.resume and trainer.resume():
        print(f"resuming {config.method_name} from step {trainer.step}", file=sys.stderr)
    try:
        record = trainer.train()
    except KeyboardInterrupt:
        path = trainer.save_checkpoint()
        print(f"interrupted at step {trainer.step}; saved {path}; continue with --resume", file=sys.stderr)
        return EXIT_INTERRUPTED
    summary = ", ".join(f"{k} {record[k]:.4g}" for k in ("loss", "psnr", "inv_s") if k in record)
    print(f"trained {config.method_name} for {trainer.step} steps in {trainer.train_seconds:.1f} s ({summary}); "
          f"run folder {run_dir}")
    if args.export_mesh:
        from va_plugin.export.mesh import export_run_mesh

        path = export_run_mesh(trainer.pipeline, run_dir / "mesh.ply")
        print(f"mesh written to {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
