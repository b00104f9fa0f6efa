"""User-facing errors.

Anything a user can cause (a bad path, a malformed file, a contradictory option) raises ``VAError``
with one line that says what is wrong and how to fix it. The command-line entry points print that
line and exit with status 2 instead of showing a traceback.
"""


class VAError(Exception):
    """An error caused by the user's input or options; its message is shown as one line."""


class DataError(VAError):
    """A data folder, image or camera file that cannot be used."""


class ConfigError(VAError, ValueError):
    """An unknown method, preset, option, an option's value out of its range, or an inconsistent
    combination of options (also a ``ValueError``, so code that builds components directly can catch
    it as one)."""


class CheckpointError(VAError):
    """A checkpoint that is missing, corrupt, or belongs to another method."""
