"""What :func:`~va_plugin.api.build_config` makes of its options: overrides as ``--set`` assignments, the
generator options (views, elevation, field of view, rig, masks) on the dataparser config."""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from dataclasses import fields
from pathlib import Path
from typing import Any

from va_plugin.data.dataparsers import resolve_dataparser
from va_plugin.data.dataparsers.rigged import RigDataParserConfig
from va_plugin.data.rigfile import builtin_rigs, is_rig_file
from va_plugin.engine.trainer import TrainerConfig
from va_plugin.errors import ConfigError
from va_plugin.utils.arguments import check_kind
from va_plugin.utils.paths import optional_user_path

RECOMMENDED_METHOD = "neus"
QUALITIES = {"fast": "fast", "default": None, "accurate": "accurate"}
"""``quality`` -> the method's preset."""
VIEW_COUNTS = (4, 8, 12, 16)
"""SyncDreamer: the training view counts one can ask for (uniform in azimuth), besides ``"all"``."""

# generator option -> (dataparser option, the formats that have it)
GENERATOR_OPTIONS = {"views": ("num_views", "syncdreamer"),
                     "elevation": ("elevation_deg", "syncdreamer and rig-format"),
                     "fov": ("fov_deg", "rig-format (perspective)"),
                     "rig": ("rig", "zero123pp"), "masks": ("masks", "generator")}


def override_text(key: str, value: Any) -> str:
    """``key=value`` as ``--set`` reads it (lists as JSON, booleans as true/false)."""
    if isinstance(value, bool):
        value = "true" if value else "false"
    elif isinstance(value, (list, tuple)):
        value = json.dumps(list(value))
    return f"{key.replace('__', '.')}={value}"


def override_list(overrides: Mapping[str, Any] | Iterable[str] | None) -> list[str]:
    """``overrides`` (a mapping, ``key=value`` strings or one string) as ``--set`` assignments."""
    check_kind("overrides", overrides, Mapping, Iterable, str, optional=True)
    if overrides is None:
        return []
    if isinstance(overrides, Mapping):
        return [override_text(key, value) for key, value in overrides.items()]
    if isinstance(overrides, str):
        return [overrides]
    return list(overrides)


def apply_generator_options(parser_config, given: dict[str, Any]) -> None:
    """Copy the generator options that were given onto the dataparser config (a dataclass), refusing ones
    it has no field for."""
    options = {f.name for f in fields(parser_config)}
    for name, (option, formats) in GENERATOR_OPTIONS.items():
        value = given.get(name)
        if value is None:
            continue
        if value == "all":  # every view the input has: the generators' parsers train on all by default
            if option in options:
                setattr(parser_config, option, max(VIEW_COUNTS))
            continue
        if option not in options or (name == "rig" and isinstance(parser_config, RigDataParserConfig)):
            raise ConfigError(f"--{name} applies to {formats} inputs only")
        setattr(parser_config, option, value)


def check_views(views: Any) -> Any:
    """``views``: one of :data:`VIEW_COUNTS`, ``"all"`` or None; anything else is refused."""
    if views is None or views == "all" or (isinstance(views, int) and not isinstance(views, bool)
                                           and views in VIEW_COUNTS):
        return views
    raise ConfigError(f"views {views!r} is not one of 4, 8, 12, 16 or all")


def split_rig_option(rig: str | Path | None, data_format: str) -> tuple[str | None, str | Path | None, str]:
    """``rig`` as ``(zero123pp version, rig file, data format)``: a rig file (.json, .yaml) is read as the
    input's layout, a built-in rig's name is its format, anything else is a Zero123++ version."""
    if rig is None:
        return None, None, data_format
    if is_rig_file(rig):
        return None, rig, data_format
    if str(rig) in builtin_rigs():
        if data_format not in ("auto", str(rig)):
            raise ConfigError(f"--rig {rig} and --data-format {data_format} disagree; give one of them")
        return None, None, str(rig)
    return str(rig), None, data_format


def input_dataparser(default: Any, data: Path, data_format: str, rig: str | Path | None,
                     generator_options: dict[str, Any]) -> Any:
    """The dataparser config that reads ``data`` (its format detected unless ``data_format`` names it;
    ``default``: the method's own), with ``rig`` (see :func:`split_rig_option`) and the generator options
    (:data:`GENERATOR_OPTIONS`) applied."""
    version, rig_file, data_format = split_rig_option(rig, data_format)
    parser = resolve_dataparser(data, data_format, default, rig_file=optional_user_path(rig_file, "rig"))
    apply_generator_options(parser, {**generator_options, "views": check_views(generator_options.get("views")),
                                     "rig": version})
    return parser


def set_run_options(config: TrainerConfig, steps: int | None, seed: int | None, device: str | None,
                    progress: bool) -> None:
    """Set the run options that were given (None: the method's own) on ``config``, in place."""
    if steps is not None:
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise ConfigError(f"--steps must be at least 1, got {steps}")
        config.max_steps = steps
    if seed is not None:
        config.seed = seed
    if device is not None:
        config.device = device
    config.progress = progress
