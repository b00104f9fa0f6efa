"""The kinds of value an API function takes, checked at its call before any work: a value of another kind
(a list for a method name, a text for a step count, a number for ``progress``) is one line
(:class:`~va_plugin.errors.ConfigError`) naming the argument, never a ``TypeError`` from deep inside."""

from __future__ import annotations

import numbers
import threading
from collections.abc import Iterable, Mapping
from typing import Any

from va_plugin.errors import ConfigError

KIND_NAMES = {str: "a str", bool: "True or False", int: "an int", numbers.Integral: "an int", float: "a number",
              numbers.Real: "a number", Mapping: "a dict", Iterable: "a list"}


def _shown(value: Any) -> str:
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 40 else text[:37] + '...'}"


def check_kind(name: str, value: Any, *kinds: type, optional: bool = False) -> None:
    """Refuse ``value`` unless it is of one of ``kinds`` (None too when ``optional``). ``True`` and
    ``False`` are no numbers here, and a text is no list."""
    if value is None and optional:
        return
    refused = (bool, str)  # True is an int and a text is iterable in Python, but no count and no list here
    fits = isinstance(value, kinds) and not any(isinstance(value, kind) and kind not in kinds for kind in refused)
    if not fits:
        names = [KIND_NAMES.get(kind, f"a {kind.__name__}") for kind in kinds] + (["None"] if optional else [])
        raise ConfigError(f"{name} must be {' or '.join(names)}, got {_shown(value)}")


def check_kinds(optional: bool = False, **values: tuple[Any, type | tuple[type, ...]]) -> None:
    """:func:`check_kind` for each ``name=(value, kinds)``."""
    for name, (value, kinds) in values.items():
        check_kind(name, value, *(kinds if isinstance(kinds, tuple) else (kinds,)), optional=optional)


def check_hooks(progress: Any = None, stop: Any = None, on_message: Any = None) -> None:
    """Refuse a ``progress`` or ``on_message`` that cannot be called and a ``stop`` that is neither a
    ``threading.Event`` nor callable, before the data is read (not at the first step)."""
    for name, value in (("progress", progress), ("on_message", on_message)):
        if value is not None and not callable(value):
            raise ConfigError(f"{name} must be a function (or None), got {_shown(value)}")
    if stop is not None and not isinstance(stop, threading.Event) and not callable(stop):
        raise ConfigError(f"stop must be a threading.Event or a function returning True to stop (or None), "
                          f"got {_shown(stop)}")
