"""The methods shipped with va-plugin: each name and where its MethodSpecification lives.

The one list of them: ``setup.py`` registers each as a ``va_plugin.methods`` entry point, and
``va_plugin.registry`` loads them from here (so they are found without an installed package too). This
file imports nothing, so the registry can read it while the method modules import the registry."""

BUILTIN_METHODS = {
    "neus": "method_configs.neus:neus",
    "ngp": "method_configs.ngp:ngp",
    "va-neus": "method_configs.va_neus:va_neus",
    "va-ngp": "method_configs.va_ngp:va_ngp",
}
