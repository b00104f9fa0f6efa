"""``va-demo``: train on the embedded default scene, then export, render and score the result.

Everything is generated on the fly (no download, no shared data). Re-running continues an
interrupted run and skips a finished one.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from va_plugin.api import (
    EVAL_FILE,
    TrainingInterrupted,
    build_config,
    evaluate,
    export_mesh,
    load_run,
    train,
)
from va_plugin.bench.scenes import default_scene
from va_plugin.cli.common import EXIT_INTERRUPTED, ArgumentParser, add_quiet_option, friendly_errors, path_argument
from va_plugin.data.images import read_image, write_image
from va_plugin.engine.run_folder import is_run_folder
from va_plugin.export.render import render_turntable

DEMO_STEPS: dict = {"neus": 1000}
"""The demo's step budget per method where it differs from the method's own (a short demo)."""


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="va-demo", description=__doc__.splitlines()[0])
    parser.add_argument("--method", default="neus", help="registered method to train (default neus)")
    parser.add_argument("--preset", default=None, help="preset of the method")
    parser.add_argument("--output-dir", type=path_argument, default="outputs/demo", help="run folder")
    parser.add_argument("--steps", type=int, default=None,
                        help="step budget (default: the preset's or the method's own)")
    parser.add_argument("--device", default=None, help="auto, cpu or cuda[:N]")
    parser.add_argument("--resolution", type=int, default=256, help="image size of the default scene")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    parser.add_argument("--overwrite", action="store_true",
                        help="write into --output-dir even when it holds other files or another run")
    add_quiet_option(parser)
    return parser


def contact_sheet(frames: list[Path], out: Path, columns: int = 8) -> Path:
    """Turntable frames tiled into one PNG (for READMEs and quick looks)."""
    images = [read_image(p)[:, :, :3] for p in frames[: columns * max(1, len(frames) // columns)]]
    rows = [np.concatenate(images[i:i + columns], axis=1) for i in range(0, len(images), columns)]
    write_image(out, np.concatenate(rows, axis=0))
    return out


def demo_config(args: argparse.Namespace, resolve_data: bool = True):
    """The config the demo trains: the method's on the default scene, with the demo's step budget unless a
    preset or ``--steps`` is asked for."""
    steps = args.steps if args.steps is not None or args.preset else DEMO_STEPS.get(args.method)
    return build_config(args.method, default_scene(args.resolution) if resolve_data else None, preset=args.preset,
                        steps=steps, device=args.device, out=args.output_dir, progress=show_progress(args))


def show_progress(args: argparse.Namespace) -> bool:
    return not (args.no_progress or args.quiet)


@friendly_errors
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    config = demo_config(args)
    if not args.quiet:
        print(f"default scene: {default_scene(args.resolution)}")
    try:
        run = train(config, resume=is_run_folder(config.output_dir), overwrite=args.overwrite,
                    on_message=None if args.quiet else print)
    except TrainingInterrupted as interrupt:
        print(f"{interrupt}; run va-demo again to continue", file=sys.stderr)
        return EXIT_INTERRUPTED
    loaded = load_run(run, args.device)
    files = export_mesh(loaded, texture=False)
    # the mesh just written is the one scored, and the scored views are the ones saved: nothing twice
    result = evaluate(loaded, image_scale=0.5, max_views=4, progress=show_progress(args), mesh=files.mesh,
                      render_dir=run / "renders" / "test_views")
    frames = render_turntable(loaded.pipeline.model, run / "renders" / "turntable", n_frames=8, resolution=128,
                              progress=show_progress(args))
    sheet = contact_sheet([f for f in frames if f.suffix == ".png"], run / "turntable.png")
    steps, seconds = int(loaded.state["step"]), float(loaded.state["train_seconds"])
    if not args.quiet:
        print()
    print(f"{config.method_name} on the default scene: {steps} steps, {seconds:.0f} s of training")
    print("  Chamfer distance {cd:.4f}, volume IoU {iou:.3f}, F-score@0.02 {fscore:.3f}".format(**result))
    lp = f", LPIPS {result['lpips']:.3f}" if "lpips" in result else ""
    print(f"  held-out views (128 px): PSNR {result['psnr']:.2f} dB, SSIM {result['ssim']:.3f}{lp}")
    print(f"  mesh {files.path}, turntable {sheet}, metrics {run / EVAL_FILE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
