"""The methods shipped with va-plugin, each a MethodSpecification (also listed as entry points)."""

from method_configs.neus import neus

BUILTIN_METHODS = {"neus": neus}
