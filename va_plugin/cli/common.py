"""Shared pieces of the command-line entry points: one clear line and exit 2 on user errors."""

from __future__ import annotations

import functools
import sys
import warnings
from collections.abc import Callable

from va_plugin.engine.run_folder import check_output_dir
from va_plugin.errors import VAError, one_line_warning
from va_plugin.utils.interrupts import terminate_as_interrupt

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


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


__all__ = ["EXIT_INTERRUPTED", "EXIT_USER_ERROR", "check_output_dir", "friendly_errors"]
