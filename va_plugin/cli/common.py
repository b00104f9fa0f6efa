"""Shared pieces of the command-line entry points: one clear line and exit 2 on user errors (bad
options, as argparse finds them or as the package does, and bad input)."""

from __future__ import annotations

import argparse
import functools
import sys
import warnings
from collections.abc import Callable

from va_plugin.engine.run_folder import check_output_dir
from va_plugin.errors import VAError, one_line_warning
from va_plugin.utils.interrupts import terminate_as_interrupt

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


class ArgumentParser(argparse.ArgumentParser):
    """argparse whose mistakes (an unknown flag, a missing or mistyped value) read like every other bad option:
    one line ``error: ...`` saying where the options are listed, exit status 2, no usage block above it."""

    def error(self, message: str):
        self.exit(EXIT_USER_ERROR, f"error: {message} (see {self.prog} --help)\n")


def friendly_errors(main: Callable[..., int]) -> Callable[..., int]:
    """Turn VAError into ``error: <message>`` on stderr with exit status 2 (no traceback); Ctrl-C, and SIGTERM
    taken like it, into ``interrupted`` and exit status 130 once the command has saved what it can."""

    @functools.wraps(main)
    def wrapper(*args, **kwargs) -> int:
        shown = warnings.showwarning
        warnings.showwarning = one_line_warning
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


__all__ = ["EXIT_INTERRUPTED", "EXIT_USER_ERROR", "ArgumentParser", "check_output_dir", "friendly_errors"]
