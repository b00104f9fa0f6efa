"""``va-export mesh|render|diagnostics --load-dir RUN``: meshes and renders of a trained run."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import List, Optional

from va_plugin.cli.common import friendly_errors
from va_plugin.cli.run import load_run


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="va-export", description="Export meshes and renders of a trained run.")
    sub = parser.add_subparsers(dest="what", required=True)
    mesh = sub.add_parser("mesh", help="marching-cubes mesh with vertex colours, or textured with --texture")
    mesh.add_argument("--load-dir", type=Path, required=True, help="run folder of va-train")
    mesh.add_argument("--output", type=Path, default=None, help="mesh file: .ply, .obj or .glb (default RUN/mesh.ply; RUN/mesh.glb with --texture)")
    mesh.add_argument("--resolution", type=int, default=128, help="marching-cubes grid resolution (default %(default)s)")
    mesh.add_argument("--largest-component", action="store_true", help="keep only the largest connected part")
    mesh.add_argument("--texture", action="store_true",
                      help="UV-unwrap the mesh and bake a texture from the input views (.glb or .obj+.mtl+.png)")
    mesh.add_argument("--texture-size", type=int, default=1024, help="texture side in texels, a power of two (default %(default)s)")
    mesh.add_argument("--max-faces", type=int, default=None,
                      help="with --texture: simplify the mesh to at most this many faces before the UV unwrap "
                      "(default 40000; 0 keeps every face)")
    mesh.add_argument("--fusion", choices=("robust", "mean"), default="robust",
                      help="how disagreeing views are fused per texel: robust consensus or weighted mean (default %(default)s)")
    mesh.add_argument("--no-harmonise", action="store_true",
                      help="robust fusion: skip levelling each view's colour gains against the others")
    mesh.add_argument("--use-inconsistency", action="store_true",
                      help="view-adaptive runs: weight each view down where its inconsistency map is high")
    render = sub.add_parser("render", help="held-out views and a turntable (PNG frames and MP4)")
    render.add_argument("--load-dir", type=Path, required=True, help="run folder of va-train")
    render.add_argument("--output-dir", type=Path, default=None, help="default RUN/renders")
    render.add_argument("--scale", type=float, default=1.0, help="resolution factor of the held-out views")
    render.add_argument("--max-views", type=int, default=None, help="render at most this many held-out views")
    render.add_argument("--frames", type=int, default=24, help="turntable frames")
    render.add_argument("--turntable-resolution", type=int, default=128, help="turntable image size")
    diag = sub.add_parser("diagnostics", help="view-adaptive runs: attention heat map and per-view inconsistency maps")
    diag.add_argument("--load-dir", type=Path, required=True, help="run folder of va-train")
    diag.add_argument("--output-dir", type=Path, default=None, help="default RUN")
    diag.add_argument("--scale", type=float, default=0.5, help="resolution factor of the inconsistency maps")
    for p in (mesh, render, diag):
        p.add_argument("--device", default=None, help="auto, cpu or cuda[:N]")
    return parser


@friendly_errors
def main(argv: Optional[List[str]] = None) -> int:
    args = build_parser().parse_args(argv)
    from va_plugin.errors import ConfigError
    from va_plugin.utils.memory import check_image_side, check_mesh_resolution, check_render_size

    if getattr(args, "resolution", 2) < 2 or getattr(args, "frames", 1) < 1 or getattr(args, "scale", 1.0) <= 0:
        raise ConfigError("--resolution must be at least 2, --frames at least 1 and --scale positive")
    if args.what == "mesh":  # options are checked before minutes of marching cubes, not after
        from va_plugin.export.mesh import MESH_FORMATS
        from va_plugin.export.texture import check_texture_size
        from va_plugin.export.writing import check_texture_output

        if args.output is None:
            args.output = args.load_dir / ("mesh.glb" if args.texture else "mesh.ply")
        if args.output.suffix.lower() not in MESH_FORMATS:
            raise ConfigError(f"unknown mesh format {args.output.suffix!r}; use one of {', '.join(MESH_FORMATS)}")
        if args.texture:
            check_texture_size(args.texture_size)
            check_texture_output(args.output)
            if args.max_faces is not None and (args.max_faces < 0 or 0 < args.max_faces < 4):
                raise ConfigError(f"--max-faces must be 0 (keep every face) or at least 4, got {args.max_faces}")
        elif args.max_faces is not None:
            raise ConfigError("--max-faces simplifies the mesh for its texture: it needs --texture")
        check_mesh_resolution(args.resolution)
    pipeline, _ = load_run(args.load_dir, device=args.device)
    if args.what in ("render", "diagnostics"):
        views = pipeline.datamanager.test if args.what == "render" and pipeline.datamanager.test is not None \
            else pipeline.datamanager.train
        check_render_size(views.cameras.width, views.cameras.height, args.scale)
        if args.what == "render":
            check_image_side(args.turntable_resolution, "--turntable-resolution")
    if args.what == "mesh":
        from va_plugin.export.mesh import extract_mesh, write_mesh

        mesh = extract_mesh(pipeline.model, resolution=args.resolution, largest_component=args.largest_component,
                            with_color=not args.texture)
        if args.texture:
            from va_plugin.export.atlas import MAX_TEXTURE_FACES
            from va_plugin.export.texture import texture_run_mesh

            textured, report, written = texture_run_mesh(pipeline, mesh, args.output, args.texture_size, args.fusion,
                                                         args.use_inconsistency,
                                                         harmonise_views=False if args.no_harmonise else None,
                                                         max_faces=MAX_TEXTURE_FACES if args.max_faces is None
                                                         else args.max_faces)
            seen = report.seen / max(report.covered, 1)
            simplified = f" (simplified from {len(mesh.faces)})" if len(textured.faces) < len(mesh.faces) else ""
            print(f"textured mesh with {len(textured.vertices)} vertices, {len(textured.faces)} faces{simplified} "
                  f"and a {args.texture_size}^2 texture ({seen:.1%} of texels seen by an input view) written to "
                  + ", ".join(str(p) for p in written))
            return 0
        write_mesh(mesh, args.output)
        print(f"mesh with {len(mesh.vertices)} vertices and {len(mesh.faces)} faces written to {args.output}")
        return 0
    if args.what == "diagnostics":
        from va_plugin.adaptive.diagnostics import write_diagnostics

        out_dir = args.output_dir if args.output_dir is not None else args.load_dir
        written = write_diagnostics(pipeline, out_dir, scale=args.scale, progress=True)
        if not written:
            raise ConfigError("nothing to show: the run is not view-adaptive, or its adaptive phases never ran "
                              "(see view_residuals.json in the run folder)")
        print("wrote " + ", ".join(str(p) for p in written))
        return 0
    from va_plugin.export.render import render_test_views, render_turntable

    out_dir = args.output_dir if args.output_dir is not None else args.load_dir / "renders"
    views = render_test_views(pipeline, out_dir / "test_views", scale=args.scale, max_views=args.max_views)
    frames = render_turntable(pipeline.model, out_dir / "turntable", n_frames=args.frames,
                              resolution=args.turntable_resolution)
    print(f"wrote {len(views)} held-out views and {len(frames) - 1} turntable frames (+ video) to {out_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
