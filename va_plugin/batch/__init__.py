"""``va-batch``: reconstruct a folder of generator outputs and scenes, one job per object.

- :mod:`~va_plugin.batch.inputs`: which objects a folder (or a list file) holds, and their names;
- :mod:`~va_plugin.batch.job`: the job of one object (train, export the mesh, evaluate);
- :mod:`~va_plugin.batch.engines`: who runs the jobs: ``local`` (a pool of worker processes) or ``ray``;
- :mod:`~va_plugin.batch.manifest`: the settings and the manifest (one JSON line per finished object);
- :mod:`~va_plugin.batch.summary`: ``summary.csv``, ``summary.md`` and the contact sheet.
"""
