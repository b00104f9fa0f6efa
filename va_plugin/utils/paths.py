"""One resolution of every path a user gives, at the boundary of each command and API function.

``~`` is expanded, then the path is made absolute with its symbolic links followed and its ``..`` removed
(:func:`user_path`); every later step (the folder checks, the manifest, the lock, the trainer, the exports)
uses that one path, so a run cannot be split between ``~/x`` and a literal ``./~/x``. A value that is no
path (a number, a list, None where a path is needed), an empty one, a ``~user`` that names no user or a
loop of symbolic links is one line (:class:`~va_plugin.errors.ConfigError`) naming the option.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from va_plugin.errors import ConfigError


def path_text(value: Any, what: str) -> str:
    """``value`` as text, when it is a path (a ``str`` or ``os.PathLike``) that is not empty."""
    if isinstance(value, bytes) or not isinstance(value, (str, os.PathLike)):
        shown = type(value).__name__ if value is not None else "None"
        raise ConfigError(f"{what} must be a path (a str or pathlib.Path), got {shown}")
    text = os.fspath(value)
    if not isinstance(text, str):
        raise ConfigError(f"{what} must be a path given as text, got {type(text).__name__}")
    if not text.strip():
        raise ConfigError(f"{what} is empty; give a file or folder")
    if "\0" in text:
        raise ConfigError(f"{what} {text!r} holds a NUL character")
    return text


def user_path(value: Any, what: str) -> Path:
    """``value`` (a ``str`` or ``os.PathLike``) expanded (``~``) and resolved; ``what`` names it in errors
    (``--out``, ``out``)."""
    text = path_text(value, what)
    try:
        path = Path(text).expanduser()
    except RuntimeError:  # ~name of no user of this machine
        raise ConfigError(f"{what} {text}: {text.split('/')[0]} names no user of this machine") from None
    try:
        return path.resolve()
    except RuntimeError:  # Python before 3.13 says a loop of symbolic links this way
        raise ConfigError(f"{what} {text} cannot be used: it goes through a loop of symbolic links") from None
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise ConfigError(f"{what} {text} cannot be used: {reason}") from None


def optional_user_path(value: Any, what: str) -> Path | None:
    """:func:`user_path`, with None passed through (an option not given)."""
    return None if value is None else user_path(value, what)


def within(value: Any, folder: Path, what: str) -> Path:
    """``value`` resolved as :func:`user_path` does when absolute or starting with ``~``; otherwise taken
    inside ``folder`` (a file name of a run)."""
    text = path_text(value, what)
    if not (text.startswith("~") or Path(text).is_absolute()):
        text = os.path.join(os.fspath(folder), text)
    return user_path(text, what)
