"""``va-recon INPUT``: one command from a generator's output (or a scene folder) to a textured mesh.

It detects the input's format, trains the recommended method on every view the input has, and writes
into the output folder the mesh (``mesh.ply``, in the training frame), the textured mesh (``mesh.glb``,
which viewers open as it is, and ``mesh.obj`` with ``mesh.mtl`` and ``mesh.png``; both upright), a
turntable of it (``turntable/turntable.mp4`` and ``turntable/turntable.png``) and ``summary.json``; it ends
by printing what to open (``--quiet``: only that). It runs the same job as each object of ``va-batch``
(:func:`va_plugin.api.reconstruct`). Exit status: 0 done, 2 bad command or input (one line, checked
before any training, nothing written), 130 interrupted (continue with ``--resume``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from va_plugin.api import QUALITIES, RECOMMENDED_METHOD, TrainingInterrupted, reconstruct
from va_plugin.cli.common import (
    EXIT_INTERRUPTED,
    ArgumentParser,
    add_export_options,
    add_quiet_option,
    check_output_dir,
    export_config,
    friendly_errors,
    path_argument,
)
from va_plugin.cli.train import VIEWS_HELP, add_rig_options, parse_views
from va_plugin.data.dataparsers import FORMATS
from va_plugin.export.files import SUMMARY_FILE
from va_plugin.registry import discover_methods


def build_parser(methods) -> argparse.ArgumentParser:
    listing = ", ".join(methods)
    parser = ArgumentParser(
        prog="va-recon",
        description="Turn a multi-view generator's output (SyncDreamer, Zero123++, Wonder3D, Hunyuan3D-1, "
                    "MV-Adapter, SV3D, Era3D, CRM, 4-view grids, or any layout a rig file describes) or a scene "
                    "folder into a textured mesh, in one command.",
        epilog=f"Writes OUT/mesh.ply, OUT/mesh.glb and OUT/mesh.obj (textured, +Y up), OUT/turntable/ and "
               "OUT/summary.json. "
               f"Methods: {listing}; neus is the recommended one (va-neus is the paper's view-adaptive "
               "variant: slower, and on our benchmarks no more accurate). Step by step: va-train, then "
               "va-export mesh --texture.")
    parser.add_argument("input", type=path_argument, help="the generator's output, or a scene folder")
    parser.add_argument("--out", type=path_argument, default=None,
                        help="output folder (default: outputs/recon/<input name>)")
    parser.add_argument("--method", default=RECOMMENDED_METHOD, help="reconstruction method (default neus)")
    parser.add_argument("--quality", choices=tuple(QUALITIES), default="default",
                        help="fast: a rough mesh in about a quarter of the time; accurate: the paper's 4x256 "
                             "network for 6000 steps, hours on a CPU, meant for a GPU (default: default)")
    parser.add_argument("--views", type=parse_views, default=None, help=VIEWS_HELP + " (default: all)")
    parser.add_argument("--masks", type=path_argument, default=None,
                        help="mask folder (one image per view) or one mask image in the input's layout, "
                             "instead of the input's alpha or the color key")
    parser.add_argument("--data-format", default="auto", choices=("auto", *FORMATS),
                        help="input format (default auto: detected from the input)")
    add_rig_options(parser)
    add_export_options(parser)
    parser.add_argument("--turntable-frames", type=int, default=36,
                        help="frames of the turntable, 0 for none (default 36)")
    parser.add_argument("--steps", type=int, default=None, help="training steps (default: the method's)")
    parser.add_argument("--seed", type=int, default=None, help="random seed (default 42)")
    parser.add_argument("--device", default=None, help="auto, cpu or cuda[:N] (default auto)")
    parser.add_argument("--resume", action="store_true", help="continue an interrupted run in OUT")
    parser.add_argument("--overwrite", action="store_true",
                        help="write into OUT even when it holds other files (an earlier run there starts again)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="PATH=VALUE",
                        help="override a config value of the method (va-train METHOD --help-config lists them)")
    add_quiet_option(parser)
    return parser


def summary_lines(record: dict, out: Path) -> list[str]:
    lines = [f"done in {record['seconds']:.0f} s ({record['steps']} steps, {record['train_seconds']:.0f} s "
             f"training); {record['views']} views, masks from the {record['masks']}"]
    for key, what in (("textured_mesh", "textured mesh"), ("textured_obj", "OBJ + MTL"), ("turntable", "turntable"),
                      ("mesh", "mesh")):
        if key in record:
            lines.append(f"  {what:<14} {record[key]}")
    lines.append(f"  {'summary':<14} {out / SUMMARY_FILE}")
    return lines


def say(line: str) -> None:
    print(f"va-recon: {line}", file=sys.stderr, flush=True)


@friendly_errors
def main(argv: list[str] | None = None) -> int:
    methods = discover_methods()
    args = build_parser(methods).parse_args(argv)
    if args.out is None:
        args.out = path_argument(str(Path("outputs") / "recon" / args.input.stem))
    check_output_dir(args.out, "--out")
    try:
        result = reconstruct(args.input, args.out, method=args.method, quality=args.quality,
                             views=args.views if args.views is not None else "all", steps=args.steps,
                             device=args.device, seed=args.seed, masks=args.masks, data_format=args.data_format,
                             elevation=args.elevation, fov=args.fov, rig=args.rig, resume=args.resume,
                             overwrite=args.overwrite, export=export_config(args),
                             turntable_frames=args.turntable_frames, show_progress=not args.quiet,
                             on_message=None if args.quiet else say, overrides=list(args.overrides))
    except TrainingInterrupted as interrupt:
        print(f"{interrupt}; continue with the same command and --resume", file=sys.stderr)
        return EXIT_INTERRUPTED
    print("\n".join(summary_lines(result.record, result.run_dir)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
