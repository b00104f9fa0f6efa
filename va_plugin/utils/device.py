"""Device choice: CUDA when present, CPU otherwise, with an explicit override."""

from __future__ import annotations

import torch

from va_plugin.errors import ConfigError


def pick_device(override: str | None = None) -> torch.device:
    """The device to run on: ``override`` if given ("cpu", "cuda", "cuda:1"), else CUDA when present."""
    if override in (None, "", "auto"):
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(override)
    except RuntimeError:
        raise ConfigError(f"unknown device {override!r}; use auto, cpu or cuda[:N]") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"device {override!r} was asked for but CUDA is not available on this machine")
    return device
