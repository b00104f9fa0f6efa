"""``va-demo``: train on the embedded default scene, then export, render and score the result.

Everything is generated on the fly (no download, no shared data). Re-running continues an
interrupted run and skips a finished one.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import List, Optional

import numpy as np

from va_plugin.cli.common import EXIT_INTERRUPTED, cache_dir, friendly_errors
from va_plugin.cli.train import build_parser as build_train_parser
from va_plugin.cli.train import make_config
from va_plugin.registry import discover_methods


DEMO_STEPS: dict = {"neus": 1000}
"""The demo's step budget per method where it differs from the method's own (a short demo)."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="va-demo", description=__doc__.splitlines()[0])
    parser.add_argument("--method", default="neus", help="registered method to train (default neus)")
    parser.add_argument("--preset", default=None, help="preset of the method")
    parser.add_argument("--output-dir", type=Path, default=Path("outputs/demo"), help="run folder")
    parser.add_argument("--steps", type=int, default=None,
                        help="step budget (default: the preset's or the method's own)")
    parser.add_argument("--device", default=None, help="auto, cpu or cuda[:N]")
    parser.add_argument("--resolution", type=int, default=256, help="image size of the default scene")
    parser.add_argument("--no-progress", action="store_true")
    return parser


def contact_sheet(frames: List[Path], out: Path, columns: int = 8) -> Path:
    """Turntable frames tiled into one PNG (for READMEs and quick looks)."""
    from va_plugin.data.images import read_image, write_image

    images = [read_image(p)[:, :, :3] for p in frames[: columns * max(1, len(frames) // columns)]]
    rows = [np.concatenate(images[i:i + columns], axis=1) for i in range(0, len(images), columns)]
    write_image(out, np.concatenate(rows, axis=0))
    return out


def demo_train_args(args: argparse.Namespace, methods) -> argparse.Namespace:
    """The ``va-train`` arguments the demo trains with: va-train's defaults for every flag the demo does not
    have (generator options, seed, ...), the demo's step budget unless a preset is asked for."""
    train_args = build_train_parser(methods).parse_args([args.method])
    steps = args.steps if args.steps is not None or args.preset else DEMO_STEPS.get(args.method)
    train_args.__dict__.update(preset=args.preset, output_dir=args.output_dir, steps=steps, device=args.device,
                               no_progress=args.no_progress, default_scene_resolution=args.resolution)
    return train_args


@friendly_errors
def main(argv: Optional[List[str]] = None) -> int:
    args = build_parser().parse_args(argv)
    methods = discover_methods()
    config = make_config(demo_train_args(args, methods), methods)
    scene_dir = cache_dir() / f"default-scene-{args.resolution}"
    print(f"default scene: {scene_dir}")
    from va_plugin.engine.trainer import TrainingInterrupted, train_run

    try:
        trainer = train_run(config, resume=True, on_resume=lambda step: print(
            f"continuing the run in {args.output_dir} from step {step}")).trainer
    except TrainingInterrupted as interrupt:
        print(f"interrupted at step {interrupt.step}; saved {interrupt.checkpoint}; run va-demo again to continue",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    from va_plugin.eval.evaluate import evaluate_run
    from va_plugin.export.mesh import extract_mesh, write_mesh
    from va_plugin.export.render import render_turntable

    run = Path(args.output_dir)
    pipeline = trainer.pipeline
    mesh = extract_mesh(pipeline.model, resolution=128)
    mesh_path = write_mesh(mesh, run / "mesh.ply")
    state = {"method_name": config.method_name, "step": trainer.step, "train_seconds": trainer.train_seconds}
    # the mesh just written is the one scored, and the scored views are the ones saved: nothing twice
    result = evaluate_run(pipeline, state, image_scale=0.5, max_views=4, progress=not args.no_progress,
                          mesh=mesh, render_dir=run / "renders" / "test_views")
    frames = render_turntable(pipeline.model, run / "renders" / "turntable", n_frames=8, resolution=128,
                              progress=not args.no_progress)
    sheet = contact_sheet([f for f in frames if f.suffix == ".png"], run / "turntable.png")
    (run / "eval.json").write_text(json.dumps(result, indent=2))
    print(f"\n{config.method_name} on the default scene: {trainer.step} steps, {trainer.train_seconds:.0f} s of training")
    print("  Chamfer distance {cd:.4f}, volume IoU {iou:.3f}, F-score@0.02 {fscore:.3f}".format(**result))
    lp = f", LPIPS {result['lpips']:.3f}" if "lpips" in result else ""
    print(f"  held-out views (128 px): PSNR {result['psnr']:.2f} dB, SSIM {result['ssim']:.3f}{lp}")
    print(f"  mesh {mesh_path}, turntable {sheet}, metrics {run / 'eval.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
