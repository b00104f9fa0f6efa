"""Configuration objects in the nerfstudio style.

Every component has a dataclass config that names the class it builds (``_target``) and builds it
with ``setup(**kwargs)``. Configs are the single source of every default. Dotted overrides such as
``pipeline.model.eikonal_weight=0.05`` are applied with :func:`apply_override`, converting the
value to the type of the field it replaces.
"""

from __future__ import annotations

import ast
import dataclasses
import difflib
import functools
import importlib
import inspect
import itertools
import json
import math
import os
import re
import textwrap
import warnings
from dataclasses import dataclass, field, fields, is_dataclass
from pathlib import PurePath
from typing import Any

from va_plugin.errors import ConfigError


class Checked:
    """A config with checks across its fields (:func:`validate_config` runs them with the range rules)."""

    def validate(self, prefix: str = "") -> None:
        """Refuse combinations of values that cannot work; ``prefix``: the config's ``--set`` key."""


RENAMED_OPTIONS = {"shared_colour_weight": "shared_color_weight", "consistent_colour_cast": "consistent_color_cast",
                   "colour_key": "color_key"}
"""Old option name -> its name now: an old checkpoint's config and an old ``--set`` key still work."""


def _current_name(part: str) -> str:
    """An option's name now; an old name is taken with a one-line note."""
    if part in RENAMED_OPTIONS:
        warnings.warn(f"option {part} is now {RENAMED_OPTIONS[part]}; the old name still works for now",
                      stacklevel=3)
        return RENAMED_OPTIONS[part]
    return part


@dataclass
class InstantiateConfig(Checked):
    """A config that builds the object it describes."""

    _target: type = field(default=None, repr=False)  # type: ignore[assignment]

    def setup(self, **kwargs: Any) -> Any:
        """Build the target object from this config."""
        if self._target is None:
            raise ConfigError(f"{type(self).__name__} has no _target to build")
        return self._target(self, **kwargs)

    def __setstate__(self, state: dict) -> None:
        """Unpickling (a checkpoint's config): options added since the run was written take their
        defaults, so older runs still load, evaluate and export; options renamed since take their new
        names (:data:`RENAMED_OPTIONS`)."""
        state = {RENAMED_OPTIONS.get(name, name): value for name, value in state.items()}
        self.__dict__.update(state)
        for item in fields(self):
            if item.name in state:
                continue
            if item.default is not dataclasses.MISSING:
                setattr(self, item.name, item.default)
            elif item.default_factory is not dataclasses.MISSING:
                setattr(self, item.name, item.default_factory())


def resolve_reference(reference: str, origin: str) -> Any:
    """The object a ``module:attribute`` reference names (imported on use): how a config names a part that
    lives on a floor above it (a method in the registry, the analysis a view-adaptive field runs)."""
    if not isinstance(reference, str) or ":" not in reference:
        raise ConfigError(f"{origin}: {reference!r} must look like module:attribute")
    module_name, attribute = reference.split(":", 1)
    try:
        target: Any = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(f"{origin}: cannot import {module_name!r} ({exc})") from None
    for part in attribute.split("."):
        if not hasattr(target, part):
            raise ConfigError(f"{origin}: {module_name!r} has no attribute {attribute!r}")
        target = getattr(target, part)
    return target


def to_dict(config: Any) -> Any:
    """A JSON-friendly nested dict of a config (targets are written as their qualified names)."""
    if is_dataclass(config) and not isinstance(config, type):
        out = {}
        for f in fields(config):
            value = getattr(config, f.name)
            out[f.name] = to_dict(value)
        out["__class__"] = type(config).__name__
        return out
    if isinstance(config, type):
        return f"{config.__module__}.{config.__qualname__}"
    if isinstance(config, dict):
        return {str(k): to_dict(v) for k, v in config.items()}
    if isinstance(config, (list, tuple)):
        return [to_dict(v) for v in config]
    if isinstance(config, os.PathLike):
        return str(config)
    if isinstance(config, (int, float, str, bool)) or config is None:
        return config
    return repr(config)


def config_digest(config: Any) -> str:
    """A stable text form of a config, used to tell whether a checkpoint fits a config."""
    return json.dumps(to_dict(config), sort_keys=True)


def _convert(text: str, current: Any, name: str) -> Any:
    """Turn the text of an override into the type of the value it replaces."""
    lowered = text.strip().lower()
    if (is_dataclass(current) and not isinstance(current, type)) or isinstance(current, dict):
        raise ConfigError(f"option {name} is a group of options, not a value; set one of its keys"
                          f"{_example_key(current, name)}")
    if isinstance(current, bool):
        if lowered in ("1", "true", "yes", "on"):
            return True
        if lowered in ("0", "false", "no", "off"):
            return False
        raise ConfigError(f"option {name} takes true or false, got {text!r}")
    if isinstance(current, (int, float)):
        try:
            value = int(text) if isinstance(current, int) else float(text)
        except ValueError:
            kind = "an integer" if isinstance(current, int) else "a number"
            raise ConfigError(f"option {name} takes {kind}, got {text!r}") from None
        if not math.isfinite(value):
            raise ConfigError(f"option {name} takes a finite number, got {text!r}")
        return value
    if current is None:
        if lowered in ("none", "null"):
            return None
        for cast in (int, float):
            try:
                return cast(text)
            except ValueError:
                pass
        return text
    if isinstance(current, (tuple, list)):
        return _convert_sequence(text, current, name)
    if isinstance(current, PurePath):
        return type(current)(text)
    return text


def _convert_sequence(text: str, current: tuple | list, name: str) -> tuple | list:
    """A list override, written ``1,0.5,0``, ``[1, 0.5, 0]``, ``(1 0.5 0)`` or as JSON, each item in the type of
    the item it replaces; a tuple keeps its length (a color has three channels)."""
    body = text.strip()
    if len(body) >= 2 and (body[0], body[-1]) in (("[", "]"), ("(", ")")):
        body = body[1:-1]
    items = [item.strip().strip("'\"") for item in re.split(r"[,\s]+", body) if item.strip()]
    shown = ",".join(str(v) for v in current)
    form = f" (like {shown} or [{shown}])" if current else ""
    fixed = isinstance(current, tuple)
    if fixed and len(items) != len(current):
        raise ConfigError(f"option {name} takes {len(current)} values{form}, got {len(items)} in {text!r}")
    try:
        values = [_convert(item, current[k] if fixed else (current[0] if current else None), name)
                  for k, item in enumerate(items)]
    except ConfigError:
        kind = "numbers" if current and isinstance(current[0], (int, float)) else "values"
        raise ConfigError(f"option {name} takes {kind}{form}, got {text!r}") from None
    return type(current)(values)


def _example_key(section: Any, name: str) -> str:
    """``", e.g. a.b.c=VALUE"`` with the first key below a group of options."""
    if isinstance(section, dict):
        for key, sub in section.items():
            if is_dataclass(sub):
                return _example_key(sub, f"{name}.{key}")
        return ""
    rows = describe_options(section, name + ".")
    return f", e.g. {rows[0][0]}=VALUE (--help-config lists them)" if rows else ""


# Ranges of numeric options by their last name, checked on every override, so that a value that would
# train backwards, divide by zero or build an empty network is refused in one line before any work.
_POSITIVE = frozenset({
    "attention_dim", "attention_heads", "base_resolution", "border", "bound", "branch_layers", "branch_width",
    "checkpoint_every", "color_width", "crossings_rays", "density_threshold", "eval_chunk", "features_per_level",
    "finite_difference_cells", "hidden_width", "hull_resolution", "image_scale", "init_radius",
    "keep_checkpoints", "log_every", "max_resolution", "max_skips_in_a_row", "max_steps", "n_levels", "n_samples",
    "ortho_scale", "rays_per_batch", "resolution", "scene_radius", "sdf_width", "skip_margin",
    "snapshot_every", "softplus_beta", "update_every"})
_NON_NEGATIVE = frozenset({  # 0 is meaningful for these (off, none, all)
    "close_px", "color_layers", "consistent_color_cast", "diagnostics_scale",
    "eval_every", "eval_views", "fused_samples_per_ray", "geo_feature_dim", "hidden_layers",
    "inv_s_collapse", "inv_s_saturation", "inv_s_tolerance", "lr", "max_restores", "mesh_smoothing",
    "min_sample_weight", "n_importance", "num_threads", "position_frequencies", "schedule_steps", "sdf_layers",
    "shared_color_weight", "shared_lr_scale", "snapshot_inv_s_fraction", "spike_factor", "spike_floor",
    "start_levels", "threshold", "up_sample_steps", "warmup_steps", "weight_decay", "min_foreground_opacity",
    "final_check_after"})
_UNIT_INTERVAL = frozenset({  # shares, and colors (each channel of a background)
    "background", "crossings_start", "decay", "early_stop_transmittance", "inv_s_floor_start", "max_hole",
    "min_blob", "min_border_share", "min_foreground", "pixel_offset", "train_until"})
SEED_RANGE = (0, 2**32 - 1)
"""Seeds every random generator takes (numpy's legacy seeding stops at 2**32 - 1)."""


def _range_problem(name: str, value: float) -> str | None:
    """What is wrong with one number of option ``name`` (by its last name), or None."""
    if name in _POSITIVE and not value > 0:
        return "must be positive"
    if (name in _NON_NEGATIVE or name.endswith("_weight")) and not value >= 0:
        return "must be >= 0"
    if (name in _UNIT_INTERVAL or name.endswith("_fraction")) and not 0 <= value <= 1:
        return "must be in [0, 1]"
    if name == "direction_frequencies" and value < -1:
        return "must be -1 (no direction), 0 (raw direction) or a number of bands"
    low, high = SEED_RANGE
    if name == "seed" and not (math.isfinite(value) and value == int(value) and low <= value <= high):
        return f"must be an integer from {low} to {high} (2**32 - 1)"
    return None


def check_range(name: str, value: Any, path: str) -> None:
    """Refuse a numeric option outside its range (``*_weight`` >= 0, ``*_fraction`` in [0, 1], counts
    and sizes positive, seeds in :data:`SEED_RANGE`, ...), each number of a list option (a background color's
    channels in [0, 1]) alike; other names are not checked here."""
    for item in value if isinstance(value, (list, tuple)) else (value,):
        if isinstance(item, bool) or not isinstance(item, (int, float)):
            continue
        problem = _range_problem(name, item)
        if problem:
            raise ConfigError(f"option {path} {problem}, got {value}")


def validate_config(config: Any, prefix: str = "") -> None:
    """Every check of a config tree in one pass, whichever way the config was built: the range rules of
    :func:`check_range` on each numeric field (by its ``--set`` key), then each config's own
    ``validate(prefix)`` for what spans its fields. Raises ConfigError with the key that is wrong."""
    if not is_dataclass(config) or isinstance(config, type):
        return
    for item in fields(config):
        if item.name.startswith("_"):
            continue
        value, key = getattr(config, item.name), prefix + item.name
        if is_dataclass(value) and not isinstance(value, type):
            validate_config(value, key + ".")
        elif isinstance(value, dict):
            for name, sub in value.items():
                validate_config(sub, f"{key}.{name}.")
        else:
            check_range(item.name, value, key)
    if isinstance(config, Checked):
        config.validate(prefix)


def apply_override(config: Any, assignment: str) -> None:
    """Apply ``a.b.c=value`` to a nested config, in place, with a clear error for unknown names."""
    if "=" not in assignment:
        raise ConfigError(f"override {assignment!r} must look like name.path=value")
    path, text = assignment.split("=", 1)
    parts = [_current_name(part) for part in path.strip().split(".")]
    path = ".".join(parts)
    target = config
    for depth, part in enumerate(parts[:-1]):
        if isinstance(target, dict) and part in target:  # e.g. optimizers.fields.lr
            target = target[part]
            continue
        if not is_dataclass(target) or part not in {f.name for f in fields(target)}:
            raise ConfigError(f"unknown option {'.'.join(parts[: depth + 1])!r} in {assignment!r}"
                              f"{_nearest_keys(config, path.strip())}")
        target = getattr(target, part)
    last = parts[-1]
    if isinstance(target, dict) and last in target:  # optimizers.fields: a group, not a value
        _convert(text, target[last], path)
    if not is_dataclass(target) or last.startswith("_") or last not in {f.name for f in fields(target)}:
        raise ConfigError(f"unknown option {path!r}{_nearest_keys(config, path.strip())}")
    value = _convert(text, getattr(target, last), path)
    check_range(last, value, path)
    setattr(target, last, value)


def _nearest_keys(config: Any, key: str) -> str:
    """``"; did you mean a.b.c?"`` with the closest ``--set`` keys of ``config`` to a mistyped ``key`` (by the
    whole key, then by its last part), or a pointer to the list when nothing is close."""
    if not is_dataclass(config):
        return ""
    keys = [row[0] for row in describe_options(config)]
    close = difflib.get_close_matches(key, keys, n=3, cutoff=0.6)
    if not close:
        by_name = {}
        for k in keys:
            by_name.setdefault(k.rsplit(".", 1)[-1], []).append(k)
        names = difflib.get_close_matches(key.rsplit(".", 1)[-1], list(by_name), n=3, cutoff=0.6)
        close = [k for name in names for k in by_name[name]][:3]
    if close:
        return "; did you mean " + " or ".join(close) + "?"
    return "; --help-config lists every key"


@functools.cache
def field_docstrings(cls: type) -> dict[str, str]:
    """The docstring under each field of a dataclass and of its dataclass bases (nerfstudio's habit: a
    string literal right after the field), by field name; a subclass's text wins."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not is_dataclass(klass):
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError, SyntaxError):  # no source at hand (a frozen or generated class)
            continue
        body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
        for node, after in itertools.pairwise(body):
            if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                    and isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
                    and isinstance(after.value.value, str)):
                docs[node.target.id] = inspect.cleandoc(after.value.value)
    return docs


def describe_options(config: Any, prefix: str = "") -> list[tuple[str, Any, str]]:
    """Every ``--set`` key of a config below ``prefix``: (dotted key, current value, docstring), in the
    order of the fields; nested configs (and dicts of them, e.g. ``optimizers.fields.lr``) are walked."""
    rows: list[tuple[str, Any, str]] = []
    docs = field_docstrings(type(config))
    for item in fields(config):
        if item.name.startswith("_") or not item.repr:  # the target class, internal flags
            continue
        value, key = getattr(config, item.name), prefix + item.name
        if is_dataclass(value) and not isinstance(value, type):
            rows.extend(describe_options(value, key + "."))
        elif isinstance(value, dict) and value and all(is_dataclass(v) for v in value.values()):
            for name, sub in value.items():
                rows.extend(describe_options(sub, f"{key}.{name}."))
        else:
            rows.append((key, value, docs.get(item.name, "")))
    return rows


def format_options(config: Any, width: int = 100) -> str:
    """:func:`describe_options` as text: ``key = default`` and its docstring indented under it."""
    lines = []
    for key, value, doc in describe_options(config):
        text = str(value) if isinstance(value, (str, PurePath)) else json.dumps(to_dict(value))
        lines.append(f"{key} = {text}")
        for paragraph in (doc or "(no description)").split("\n\n"):
            lines.extend(textwrap.wrap(" ".join(paragraph.split()), width, initial_indent="    ",
                                       subsequent_indent="    "))
    return "\n".join(lines) + "\n"
