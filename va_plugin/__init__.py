"""va-plugin: the view-adaptive renderer (per-view branches + attention fusion) as a NeRF-style plugin."""

from va_plugin.utils.interrupts import interrupt_deferred

with interrupt_deferred():  # trimesh's imports swallow a Ctrl-C that lands during them (see there)
    import trimesh  # noqa: F401
