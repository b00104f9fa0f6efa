"""The methods shipped with va-plugin, each a MethodSpecification (also listed as entry points)."""

from method_configs.neus import neus
from method_configs.ngp import ngp

BUILTIN_METHODS = {"neus": neus, "ngp": ngp}
