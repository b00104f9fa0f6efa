"""Shared pieces of the command-line entry points: one clear line and exit 2 on user errors."""

from __future__ import annotations

import functools
import os
import sys
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path

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


def check_output_dir(path: Path, flag: str) -> None:
    """Refuse an output folder that cannot be one (a file, or under a file) or cannot be written, before
    any work and without creating anything; ``flag`` is the option's name as the user typed it."""
    path = Path(path).expanduser()
    if path.exists() and not path.is_dir():
        raise VAError(f"{flag} {path} is a file, not a folder; choose another {flag}")
    existing = path
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise VAError(f"{flag} {path} cannot be created: {existing} is a file")
    try:  # os.access alone says yes to root on a read-only mount
        writable = os.access(existing, os.W_OK | os.X_OK)
        if writable:
            tempfile.TemporaryFile(dir=existing).close()
    except OSError:
        writable = False
    if not writable:
        raise VAError(f"{flag} {path} cannot be written: {existing} is read-only for this user")
