"""``va-eval --load-dir RUN``: image and geometry metrics of a trained run, written to RUN/eval.json."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import List, Optional

from va_plugin.cli.common import friendly_errors
from va_plugin.cli.run import load_run
from va_plugin.errors import ConfigError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="va-eval", description="Evaluate a trained run (PSNR, SSIM, LPIPS on "
                                     "held-out views; Chamfer distance, volume IoU, F-score of its mesh).")
    parser.add_argument("--load-dir", type=Path, required=True, help="run folder of va-train")
    parser.add_argument("--scene", type=Path, default=None,
                        help="scene folder with scene.json and the ground-truth mesh (default: the run's data)")
    parser.add_argument("--output", type=Path, default=None, help="default RUN/eval.json")
    parser.add_argument("--mesh-resolution", type=int, default=128, help="marching-cubes grid of the run's mesh")
    parser.add_argument("--image-scale", type=float, default=1.0, help="render held-out views at this scale")
    parser.add_argument("--max-views", type=int, default=None, help="evaluate at most this many held-out views")
    parser.add_argument("--device", default=None, help="auto, cpu or cuda[:N]")
    parser.add_argument("--no-progress", action="store_true")
    return parser


@friendly_errors
def main(argv: Optional[List[str]] = None) -> int:
    args = build_parser().parse_args(argv)
    if args.mesh_resolution < 8 or args.image_scale <= 0:
        raise ConfigError("--mesh-resolution must be at least 8 and --image-scale positive")
    if args.scene is not None and not (args.scene / "scene.json").is_file():
        raise ConfigError(f"{args.scene} holds no scene.json")
    from va_plugin.eval.evaluate import evaluate_run

    pipeline, state = load_run(args.load_dir, device=args.device)
    result = evaluate_run(pipeline, state, args.scene, args.mesh_resolution, args.image_scale, args.max_views,
                          progress=not args.no_progress)
    output = args.output if args.output is not None else args.load_dir / "eval.json"
    tmp = output.with_name(output.name + ".tmp")  # a killed va-eval leaves no half-written eval.json
    tmp.write_text(json.dumps(result, indent=2))
    tmp.replace(output)
    shown = ", ".join(f"{k} {result[k]:.4g}" for k in ("psnr", "ssim", "lpips", "cd", "iou", "fscore") if k in result)
    print(f"{shown}; written to {output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
