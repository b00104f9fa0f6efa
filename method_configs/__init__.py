"""The methods shipped with va-plugin, each a MethodSpecification (also listed as entry points)."""

from method_configs.neus import neus
from method_configs.ngp import ngp
from method_configs.va_neus import va_neus
from method_configs.va_ngp import va_ngp

BUILTIN_METHODS = {"neus": neus, "ngp": ngp, "va-neus": va_neus, "va-ngp": va_ngp}
