"""``va-export mesh|render|diagnostics --load-dir RUN``: meshes and renders of a trained run."""

from __future__ import annotations

import argparse
import sys

from va_plugin.analysis.diagnostics import write_diagnostics
from va_plugin.api import export_mesh, load_run, render
from va_plugin.cli.common import (
    ArgumentParser,
    add_export_options,
    add_quiet_option,
    export_config,
    friendly_errors,
    path_argument,
)
from va_plugin.errors import ConfigError
from va_plugin.utils.memory import check_render_size


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="va-export", description="Export meshes and renders of a trained run.")
    sub = parser.add_subparsers(dest="what", required=True)
    mesh = sub.add_parser("mesh", help="marching-cubes mesh with vertex colors, or textured with --texture")
    mesh.add_argument("--load-dir", type=path_argument, required=True, help="run folder of va-train")
    mesh.add_argument("--output", type=path_argument, default=None,
                      help="mesh file: .ply, .obj or .glb (default RUN/mesh.ply; with --texture RUN/mesh.glb and "
                           "RUN/mesh.obj with its .mtl and .png)")
    mesh.add_argument("--overwrite", action="store_true", help="replace an existing --output file outside the run")
    mesh.add_argument("--largest-component", action="store_true", help="keep only the largest connected part")
    add_export_options(mesh, "--texture", "--resolution", ("--max-faces",))  # --max-faces: the old name of --faces
    mesh.add_argument("--no-harmonise", action="store_true",
                      help="robust fusion: skip levelling each view's color gains against the others")
    mesh.add_argument("--use-inconsistency", action="store_true",
                      help="view-adaptive runs: weight each view down where its inconsistency map is high")
    render = sub.add_parser("render", help="held-out views and a turntable (PNG frames and MP4)")
    render.add_argument("--load-dir", type=path_argument, required=True, help="run folder of va-train")
    render.add_argument("--output-dir", type=path_argument, default=None, help="default RUN/renders")
    render.add_argument("--scale", type=float, default=1.0, help="resolution factor of the held-out views")
    render.add_argument("--max-views", type=int, default=None, help="render at most this many held-out views")
    render.add_argument("--frames", type=int, default=24, help="turntable frames")
    render.add_argument("--turntable-resolution", type=int, default=128, help="turntable image size")
    diag = sub.add_parser("diagnostics", help="view-adaptive runs: attention heat map and per-view inconsistency maps")
    diag.add_argument("--load-dir", type=path_argument, required=True, help="run folder of va-train")
    diag.add_argument("--output-dir", type=path_argument, default=None, help="default RUN")
    diag.add_argument("--scale", type=float, default=0.5, help="resolution factor of the inconsistency maps")
    for p in (mesh, render, diag):
        p.add_argument("--device", default=None, help="auto, cpu or cuda[:N]")
        add_quiet_option(p)
    return parser


@friendly_errors
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.what == "mesh":
        return export_mesh_command(args)
    if args.what == "diagnostics":
        loaded = load_run(args.load_dir, args.device)
        check_render_size(loaded.pipeline.datamanager.train.cameras.width,
                          loaded.pipeline.datamanager.train.cameras.height, args.scale)
        out_dir = args.output_dir if args.output_dir is not None else args.load_dir
        written = write_diagnostics(loaded.pipeline, out_dir, scale=args.scale, progress=not args.quiet)
        if not written:
            raise ConfigError("nothing to show: the run is not view-adaptive, or its adaptive phases never ran "
                              "(see view_residuals.json in the run folder)")
        print("wrote " + ", ".join(str(p) for p in written))
        return 0
    out_dir = args.output_dir if args.output_dir is not None else args.load_dir / "renders"
    views, frames = render(args.load_dir, out_dir, scale=args.scale, max_views=args.max_views, frames=args.frames,
                           turntable_resolution=args.turntable_resolution, device=args.device,
                           progress=not args.quiet)
    print(f"wrote {len(views)} held-out views and {len(frames) - 1} turntable frames (+ video) to {out_dir}")
    return 0


def export_mesh_command(args: argparse.Namespace) -> int:
    """``va-export mesh``: the mesh with vertex colors, or the textured mesh with ``--texture``."""
    output = None if args.output is None else args.output.resolve()
    plain = output if output is not None else args.load_dir / "mesh.ply"
    export = export_config(args, "--resolution")
    files = export_mesh(args.load_dir, export=export, output=output if args.texture else None,
                        vertex_colors=None if args.texture else plain.resolve(),
                        largest_component=args.largest_component, use_inconsistency=args.use_inconsistency,
                        harmonise=False if args.no_harmonise else None, progress=not args.quiet, device=args.device,
                        overwrite=args.overwrite)
    mesh = files.mesh
    frame = f" ({frame_words(files.frame)})" if files.frame else ""
    if not args.texture:
        print(f"mesh with {len(mesh.vertices)} vertices and {len(mesh.faces)} faces written to {files.path}{frame}")
        return 0
    textured, report = files.textured, files.report
    seen = report.seen / max(report.covered, 1)
    grid, source_faces = files.textured_source
    simplified = f" (simplified from {source_faces})" if len(textured.faces) < source_faces else ""
    if grid != export.mesh_resolution:
        simplified += f" (from a {grid}^3 grid: --faces asked for more than the {export.mesh_resolution}^3 mesh has)"
    print(f"textured mesh with {len(textured.vertices)} vertices, {len(textured.faces)} faces{simplified} "
          f"and a {export.texture_size}^2 texture ({seen:.1%} of texels seen by an input view){frame} written to "
          + ", ".join(str(p) for p in files.textured_paths))
    return 0


def frame_words(record: dict) -> str:
    """A frame record (:func:`~va_plugin.export.frame.frame_record`) in a few words."""
    if record["frame"] == "upright":
        return "upright: +Y up, standing on y = 0"
    return "training frame: +Z up"


if __name__ == "__main__":
    sys.exit(main())
