"""Device choice: CUDA when present, CPU otherwise, with an explicit override."""

from __future__ import annotations

import torch

from va_plugin.errors import ConfigError

DEVICE_TYPES = ("cpu", "cuda")
"""The kinds of device the package runs on."""


def pick_device(override: str | None = None) -> torch.device:
    """The device to run on: ``override`` if given ("cpu", "cuda", "cuda:1"), else CUDA when present. An
    override that names no device of this machine (another kind, a CUDA index it lacks) is refused."""
    if not isinstance(override, (str, torch.device, type(None))):
        raise ConfigError(f"unknown device {override!r}; use auto, cpu or cuda[:N]")
    if isinstance(override, str) and not override.strip():
        raise ConfigError("--device is empty; use auto, cpu or cuda[:N]")
    if override in (None, "auto"):
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(override.strip() if isinstance(override, str) else override)
    except RuntimeError:
        raise ConfigError(f"unknown device {override!r}; use auto, cpu or cuda[:N]") from None
    if device.type not in DEVICE_TYPES:
        raise ConfigError(f"device {override!r} is not supported; use auto, cpu or cuda[:N]")
    if device.type == "cpu" and device.index not in (None, 0):
        raise ConfigError(f"device {override!r}: there is one CPU device; use cpu")
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise ConfigError(f"device {override!r} was asked for but CUDA is not available on this machine")
        count = torch.cuda.device_count()
        if device.index is not None and device.index >= count:
            raise ConfigError(f"device {override!r} was asked for but this machine has {count} CUDA "
                              f"device(s): cuda:0{f' to cuda:{count - 1}' if count > 1 else ''}")
    return device
