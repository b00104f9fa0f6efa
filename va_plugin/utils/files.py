"""Files written whole or not at all, and write failures said in one line."""

from __future__ import annotations

import contextlib
import errno
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

from va_plugin.errors import OutputError

DISK_FULL = frozenset({errno.ENOSPC, errno.EDQUOT})
"""``errno`` values of a full disk (or quota)."""
NOT_WRITABLE = frozenset({errno.EROFS, errno.EACCES, errno.EPERM})
"""``errno`` values of a place that cannot be written (read-only mount, permissions)."""


def replace_atomic(path: Path, write: Callable[[BinaryIO], None]) -> Path:
    """Write through ``write(handle)`` to a synced temporary file beside ``path``, then rename it into
    place. On any failure (a full disk, a read-only folder, an interrupt) the temporary file is removed,
    ``path`` is left as it was and the error is raised."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise
    return path


def write_atomic(path: Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to a synced temporary file beside ``path``, then rename it into place (see
    :func:`replace_atomic`)."""
    return replace_atomic(path, lambda handle: handle.write(text.encode("utf-8")))


def write_json(path: Path, data: dict[str, Any]) -> Path:
    """Write JSON whole or not at all (a killed call leaves no half-written file)."""
    return write_atomic(path, json.dumps(data, indent=2))


def write_failure(exc: OSError, path: Path | None = None) -> str:
    """What went wrong in a failed write, for one line: ``could not write PATH: REASON``."""
    where = path if path is not None else exc.filename
    reason = exc.strerror or str(exc) or type(exc).__name__
    return f"could not write {where}: {reason}" if where else f"a write failed: {reason}"


def write_advice(exc: OSError) -> str:
    """What a user can do about a failed write, by its ``errno``."""
    if exc.errno in DISK_FULL:
        return "free some disk space"
    if exc.errno in NOT_WRITABLE:
        return "make the folder writable (or move the run folder to one that is)"
    return "check the disk"


def output_error(exc: OSError, path: Path | None = None, then: str = "") -> OutputError:
    """An :class:`~va_plugin.errors.OutputError` for a failed write: what failed, why, and ``then`` (what
    was kept, how to continue)."""
    return OutputError(f"{write_failure(exc, path)}; {write_advice(exc)}" + (f"{then}" if then else ""))
