"""``va-app``: a local web page to drop a generator output on and get a textured mesh back.

It serves the page of :mod:`va_plugin.app.server` on ``--host``:``--port`` (the URL is printed) until
Ctrl-C; each run goes into a fresh folder under ``--runs``. Needs the ``app`` extra (Gradio):
``pip install -e '.[app]'``. Exit status: 0 stopped, 2 bad option (one line, nothing started).
"""

from __future__ import annotations

import argparse
import sys

from va_plugin.api import RECOMMENDED_METHOD
from va_plugin.app.settings import DEFAULT_RUNS, AppSettings
from va_plugin.cli.common import check_output_dir, friendly_errors, path_argument
from va_plugin.errors import VAError
from va_plugin.export.config import ExportConfig


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="va-app",
        description="A local web page: drop a SyncDreamer strip, a Zero123++ grid, or a zip of a Wonder3D or "
                    "transforms.json folder; see its views and masks, train with live progress, and turn the "
                    "textured mesh with the mouse.",
        epilog="Runs queue and train one at a time. Cancel stops a run with a checkpoint; Resume (or the "
               "va-recon --resume line the page shows) continues it.")
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to serve on (default 127.0.0.1: this machine only; 0.0.0.0: every interface)")
    parser.add_argument("--port", type=int, default=None, help="port (default: the first free one from 7860)")
    parser.add_argument("--runs", type=path_argument, default=str(DEFAULT_RUNS),
                        help=f"folder of the run folders, one fresh folder per run (default {DEFAULT_RUNS})")
    parser.add_argument("--device", default="auto", help="auto, cpu or cuda[:N] (default auto)")
    parser.add_argument("--method", default=RECOMMENDED_METHOD, help="reconstruction method (default neus)")
    parser.add_argument("--share", action="store_true", help="ask Gradio for a public link (needs the network; off)")
    parser.add_argument("--max-upload-mb", type=float, default=100.0, help="largest upload taken (default 100 MB)")
    sizes = parser.add_argument_group("job sizes", "the same as va-recon's options of the same name")
    sizes.add_argument("--steps", type=int, default=None, help="training steps of every run (default: the quality's)")
    sizes.add_argument("--texture-size", type=int, default=ExportConfig.texture_size,
                       help="texture side in texels (default %(default)s)")
    sizes.add_argument("--mesh-resolution", type=int, default=ExportConfig.mesh_resolution,
                       help="marching-cubes grid (default %(default)s)")
    sizes.add_argument("--turntable-frames", type=int, default=36, help="frames of the turntable (default 36)")
    sizes.add_argument("--preview-every", type=int, default=250,
                       help="training steps between preview renders, 0 for none (default 250)")
    sizes.add_argument("--threads", type=int, default=0, help="CPU threads of each run (default 0: torch's default)")
    sizes.add_argument("--set", dest="overrides", action="append", default=[], metavar="PATH=VALUE",
                       help="override a config value of every run (va-train METHOD --help-config lists them)")
    return parser


@friendly_errors
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    check_output_dir(args.runs, "--runs")
    settings = AppSettings(runs=args.runs, host=args.host, port=args.port, device=args.device, method=args.method,
                           share=args.share, max_upload_mb=args.max_upload_mb, steps=args.steps,
                           overrides=list(args.overrides), texture_size=args.texture_size,
                           mesh_resolution=args.mesh_resolution, turntable_frames=args.turntable_frames,
                           preview_every=args.preview_every, threads=args.threads).validate()
    try:
        from va_plugin.app import server  # Gradio only here: job processes re-import this module
    except ImportError as exc:
        raise VAError(f"va-app needs the app extra ({exc.name or exc}): pip install -e '.[app]'") from None
    server.launch(settings)
    return 0


if __name__ == "__main__":
    sys.exit(main())
