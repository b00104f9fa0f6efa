"""``va-eval --load-dir RUN``: image and geometry metrics of a trained run, written to RUN/eval.json."""

from __future__ import annotations

import argparse
import sys
import time

from va_plugin.api import EVAL_FILE, evaluate, load_run
from va_plugin.cli.common import ArgumentParser, friendly_errors, path_argument
from va_plugin.eval.evaluate import check_evaluate_options, check_scorable
from va_plugin.eval.mesh_render import check_supersample, textured_mesh_metrics
from va_plugin.export.config import ExportConfig, check_texture_size
from va_plugin.export.fusion import FUSIONS
from va_plugin.export.mesh import extract_mesh
from va_plugin.export.texture import bake_texture, run_views
from va_plugin.utils.files import write_json


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="va-eval", description="Evaluate a trained run (PSNR, SSIM, LPIPS on "
                                     "held-out views; Chamfer distance, volume IoU, F-score of its mesh).")
    parser.add_argument("--load-dir", type=path_argument, required=True, help="run folder of va-train")
    parser.add_argument("--scene", type=path_argument, default=None,
                        help="scene folder with scene.json and the ground-truth mesh (default: the run's data)")
    parser.add_argument("--output", type=path_argument, default=None, help="default RUN/eval.json")
    parser.add_argument("--mesh-resolution", type=int, default=ExportConfig.mesh_resolution,
                        help="marching-cubes grid of the run's mesh (default %(default)s)")
    parser.add_argument("--image-scale", type=float, default=1.0, help="render held-out views at this scale")
    parser.add_argument("--max-views", type=int, default=None, help="evaluate at most this many held-out views")
    parser.add_argument("--texture", action="store_true",
                        help="also bake a textured mesh from the input views and score its ray-cast renders at the "
                        "held-out views (mesh_psnr, mesh_ssim, mesh_lpips)")
    parser.add_argument("--texture-size", type=int, default=ExportConfig.texture_size,
                        help="texture side in texels, a power of two (default %(default)s)")
    parser.add_argument("--fusion", choices=FUSIONS, default=ExportConfig.fusion,
                        help="per-texel fusion of the views (default %(default)s)")
    parser.add_argument("--no-harmonise", action="store_true",
                        help="robust fusion: skip levelling each view's color gains against the others")
    parser.add_argument("--texture-supersample", type=int, default=1,
                        help="rays per pixel side for the textured mesh's renders (default 1: one ray through each "
                        "pixel centre, as the field's renders; 2 averages 2x2 rays, anti-aliased edges but a "
                        "box-filtered texture)")
    parser.add_argument("--device", default=None, help="auto, cpu or cuda[:N]")
    parser.add_argument("--no-progress", action="store_true")
    return parser


@friendly_errors
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    check_evaluate_options(args.scene, args.mesh_resolution, args.image_scale, args.max_views)
    if args.texture:
        check_texture_size(args.texture_size)
        check_supersample(args.texture_supersample, "--texture-supersample")
    output = args.output if args.output is not None else args.load_dir / EVAL_FILE
    loaded = load_run(args.load_dir, args.device)
    check_scorable(loaded, args.scene)  # before the mesh of --texture: no work, no eval.json
    mesh = None
    if args.texture:
        mesh = extract_mesh(loaded.pipeline.model, resolution=args.mesh_resolution, with_color=False)
    result = evaluate(loaded, scene=args.scene, mesh_resolution=args.mesh_resolution, image_scale=args.image_scale,
                      max_views=args.max_views, mesh=mesh, output=None, progress=not args.no_progress,
                      device=args.device)
    if args.texture:
        result.update(textured_mesh_scores(loaded.pipeline, mesh, args, "lpips" in result))
    write_json(output.resolve(), result)
    shown = ", ".join(f"{k} {result[k]:.4g}" for k in ("psnr", "ssim", "lpips", "cd", "iou", "fscore") if k in result)
    print(f"{shown}; written to {output}")
    if args.texture:
        print(side_by_side(result))
    return 0


def textured_mesh_scores(pipeline, mesh, args, use_lpips: bool):
    """``mesh_psnr``, ``mesh_ssim``, ``mesh_lpips`` of the run's mesh textured from its input views."""
    started = time.perf_counter()
    textured, report = bake_texture(mesh, run_views(pipeline), size=args.texture_size, fusion=args.fusion,
                                    progress=not args.no_progress,
                                    harmonise_views=False if args.no_harmonise else None)
    scores = textured_mesh_metrics(pipeline, textured, args.image_scale, args.max_views, use_lpips,
                                   progress=not args.no_progress, supersample=args.texture_supersample)
    out = {f"mesh_{k}": scores[k] for k in ("psnr", "ssim", "lpips") if k in scores}
    out["texture_params"] = {"size": args.texture_size, "fusion": args.fusion, "supersample": args.texture_supersample,
                             "harmonise": report.gains is not None, **report.summary(),
                             "seconds_total": round(time.perf_counter() - started, 2)}
    return out


def side_by_side(result) -> str:
    """The held-out scores of the field's renders and of the textured mesh's renders, one row each."""
    rows = [f"{'held-out views':<16}{'psnr':>8}{'ssim':>8}{'lpips':>8}"]
    for name, prefix in (("field", ""), ("textured mesh", "mesh_")):
        cells = "".join(f"{result[prefix + k]:>8.4f}" if prefix + k in result else f"{'-':>8}"
                        for k in ("psnr", "ssim", "lpips"))
        rows.append(f"{name:<16}{cells}")
    return "\n".join(rows)


if __name__ == "__main__":
    sys.exit(main())
