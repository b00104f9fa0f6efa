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
from va_plugin.export.frame import FRAMES
from va_plugin.utils.interrupts import terminate_as_interrupt
from va_plugin.utils.paths import user_path

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


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


def add_mesh_file_options(parser: argparse.ArgumentParser, *names: str) -> None:
    """``--faces N`` (also spelt ``names``, e.g. an old name) and ``--frame upright|training``: the face count
    and the frame of the textured mesh files."""
    parser.add_argument("--faces", *names, dest="faces", type=int, default=None, metavar="N",
                        help="face count of the textured mesh: quadric decimation to N faces before the UV unwrap "
                             "(default: at most 40000; 0 keeps every face; a mesh with fewer faces is kept as "
                             "it is, with a warning)")
    parser.add_argument("--frame", choices=FRAMES, default="upright",
                        help="frame of the GLB and OBJ files: upright (+Y up, standing on y = 0, centred on the "
                             "vertical axis, as glTF and 3D tools expect) or training (+Z up, as trained); "
                             "PLY stays in the training frame (default %(default)s)")


__all__ = ["EXIT_INTERRUPTED", "EXIT_USER_ERROR", "ArgumentParser", "add_mesh_file_options", "add_quiet_option",
           "check_output_dir", "friendly_errors", "path_argument"]
