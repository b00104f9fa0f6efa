"""The method registry.

A method is a :class:`MethodSpecification`: a full trainer config plus a one-line description and
named presets. Methods are found through the ``va_plugin.methods`` entry-point group, so a third-party
package adds one with nothing but an entry point in its own ``setup.py``::

    entry_points={"va_plugin.methods": ["my-method = my_package.configs:my_method"]}

The environment variable ``VA_PLUGIN_METHODS="name=module:attribute[,name2=module2:attr2]"`` adds
methods without installing anything (handy for experiments and tests).
"""

from __future__ import annotations

import copy
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import metadata

from method_configs import BUILTIN_METHODS
from va_plugin.config import resolve_reference
from va_plugin.errors import ConfigError

ENTRY_POINT_GROUP = "va_plugin.methods"
ENV_VAR = "VA_PLUGIN_METHODS"


@dataclass
class Preset:
    """A named change to a method's config (for example a faster or a more accurate variant)."""

    description: str
    apply: Callable[[object], None]


@dataclass
class MethodSpecification:
    """What a method is: its trainer config, a one-line description and its presets."""

    config: object
    """The full ``TrainerConfig`` of the method, with every default."""
    description: str
    """One line shown by ``va-train --help``."""
    presets: dict[str, Preset] = field(default_factory=dict)
    """Named variants, applied with ``--preset NAME``."""

    def make_config(self, preset: str | None = None):
        """A fresh copy of the method's config, with a preset applied when one is named."""
        config = copy.deepcopy(self.config)
        if preset not in (None, "", "default"):
            if preset not in self.presets:
                known = ", ".join(["default", *sorted(self.presets)])
                raise ConfigError(f"unknown preset {preset!r}; this method has: {known}")
            self.presets[preset].apply(config)
        return config


def _load_reference(reference: str, origin: str) -> MethodSpecification:
    """Import ``module:attribute`` and check that it is a MethodSpecification."""
    spec = resolve_reference(reference, origin)
    if not isinstance(spec, MethodSpecification):
        raise ConfigError(f"{origin}: {reference!r} is a {type(spec).__name__}, not a MethodSpecification")
    return spec


def _entry_point_methods() -> dict[str, MethodSpecification]:
    methods = {}
    for entry_point in metadata.entry_points(group=ENTRY_POINT_GROUP):
        spec = entry_point.load()
        if not isinstance(spec, MethodSpecification):
            raise ConfigError(f"entry point {entry_point.name!r} of {ENTRY_POINT_GROUP} is not a MethodSpecification")
        methods[entry_point.name] = spec
    return methods


def _environment_methods() -> dict[str, MethodSpecification]:
    methods = {}
    text = os.environ.get(ENV_VAR, "").strip()
    for item in filter(None, (part.strip() for part in text.split(","))):
        if "=" not in item:
            raise ConfigError(f"{ENV_VAR}: {item!r} must look like name=module:attribute")
        name, reference = (s.strip() for s in item.split("=", 1))
        methods[name] = _load_reference(reference, ENV_VAR)
    return methods


def builtin_methods() -> dict[str, MethodSpecification]:
    """The methods shipped in ``method_configs`` (also reachable without an installed package)."""
    return {name: _load_reference(reference, "method_configs") for name, reference in BUILTIN_METHODS.items()}


def discover_methods() -> dict[str, MethodSpecification]:
    """Every method: the built-in ones, the entry points, then the environment variable (last wins)."""
    methods = builtin_methods()
    methods.update(_entry_point_methods())
    methods.update(_environment_methods())
    return dict(sorted(methods.items()))


def get_method(name: str) -> MethodSpecification:
    """One method by name, with a clear error listing the known ones."""
    methods = discover_methods()
    if name not in methods:
        raise ConfigError(f"unknown method {name!r}; known methods: {', '.join(methods)}")
    return methods[name]
