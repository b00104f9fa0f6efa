"""Shared pieces of the command-line entry points: one clear line and exit 2 on user errors (bad
options, as argparse finds them or as the package does, and bad input)."""

from __future__ import annotations

import argparse
import functools
import sys
import warnings
from collections.abc import Callable
from pathlib import Path

from va_plugin.engine.run_folder import check_output_dir
from va_plugin.errors import VAError, once_each
from va_plugin.export.atlas import MAX_TEXTURE_FACES
from va_plugin.export.config import ExportConfig
from va_plugin.export.frame import FRAMES
from va_plugin.export.fusion import FUSIONS
from va_plugin.utils.interrupts import EXIT_INTERRUPTED, terminate_as_interrupt
from va_plugin.utils.paths import user_path

EXIT_USER_ERROR = 2


class ArgumentParser(argparse.ArgumentParser):
    """argparse whose mistakes (an unknown flag, a missing or mistyped value) read like every other bad option:
    one line ``error: ...`` saying where the options are listed, exit status 2, no usage block above it."""

    def error(self, message: str):
        self.exit(EXIT_USER_ERROR, f"error: {message} (see {self.prog} --help)\n")


def path_argument(text: str) -> Path:
    """A path option's value as every later step uses it: ``~`` expanded, absolute, symbolic links
    followed (:func:`~va_plugin.utils.paths.user_path`); one that cannot be is argparse's one-line error."""
    try:
        return user_path(text, "path")
    except VAError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def friendly_errors(main: Callable[..., int]) -> Callable[..., int]:
    """Turn VAError into ``error: <message>`` on stderr with exit status 2 (no traceback); Ctrl-C, and SIGTERM
    taken like it, into ``interrupted`` and exit status 130 once the command has saved what it can."""

    @functools.wraps(main)
    def wrapper(*args, **kwargs) -> int:
        shown = warnings.showwarning
        warnings.showwarning = once_each()
        try:
            with terminate_as_interrupt():
                return main(*args, **kwargs)
        except VAError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return EXIT_USER_ERROR
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED
        finally:
            warnings.showwarning = shown

    return wrapper


def add_quiet_option(parser: argparse.ArgumentParser) -> None:
    """``--quiet``: only the final summary is printed (warnings and errors still show)."""
    parser.add_argument("--quiet", action="store_true",
                        help="print only the final summary: no progress bars or lines, no stage lines or events "
                             "(warnings and errors still show)")


def add_export_options(parser: argparse.ArgumentParser, texture_switch: str = "--no-texture",
                       resolution_flag: str = "--mesh-resolution", faces_names: tuple[str, ...] = ()) -> None:
    """The options of :class:`~va_plugin.export.config.ExportConfig`, their defaults its own: the mesh grid
    (``resolution_flag``), the texture switch (``--texture`` turns it on, ``--no-texture`` off), its size,
    the fusion, ``--faces N`` (also spelt ``faces_names``, e.g. an old name) and ``--frame``. Read them back
    with :func:`export_config`."""
    default = ExportConfig()
    parser.add_argument(resolution_flag, dest="mesh_resolution", type=int, default=default.mesh_resolution,
                        help="marching-cubes grid of the mesh (default %(default)s)")
    if texture_switch == "--texture":
        parser.add_argument("--texture", action="store_true",
                            help="UV-unwrap the mesh and bake a texture from the input views (.glb or .obj+.mtl+.png)")
    else:
        parser.add_argument("--no-texture", dest="texture", action="store_false",
                            help="vertex colors only (no mesh.glb or mesh.obj, no turntable); mesh.ply is always "
                                 "written")
    parser.add_argument("--texture-size", type=int, default=default.texture_size,
                        help="texture side in texels, a power of two (default %(default)s)")
    parser.add_argument("--fusion", choices=FUSIONS, default=default.fusion,
                        help="how disagreeing views are fused per texel: robust consensus or weighted mean "
                             "(default %(default)s)")
    parser.add_argument("--faces", *faces_names, dest="faces", type=int, default=None, metavar="N",
                        help=f"face count of the textured mesh: quadric decimation to N faces before the UV unwrap "
                             f"(default: at most {MAX_TEXTURE_FACES}; 0 keeps every face; a mesh with fewer faces "
                             "is extracted again on a finer grid, or kept as it is with a warning)")
    parser.add_argument("--frame", choices=FRAMES, default=default.frame,
                        help="frame of the GLB and OBJ files: upright (+Y up, standing on y = 0, centred on the "
                             "vertical axis, as glTF and 3D tools expect) or training (+Z up, as trained); "
                             "PLY stays in the training frame (default %(default)s)")


def export_config(args: argparse.Namespace, resolution_flag: str = "--mesh-resolution") -> ExportConfig:
    """The :class:`~va_plugin.export.config.ExportConfig` of the options :func:`add_export_options` added,
    validated (one line on a bad one)."""
    export = ExportConfig(mesh_resolution=args.mesh_resolution, texture=args.texture, texture_size=args.texture_size,
                          faces=args.faces, fusion=args.fusion, frame=args.frame)
    export.validate(resolution_flag=resolution_flag)
    return export


__all__ = ["EXIT_INTERRUPTED", "EXIT_USER_ERROR", "ArgumentParser", "add_export_options", "add_quiet_option",
           "check_output_dir", "export_config", "friendly_errors", "path_argument"]
