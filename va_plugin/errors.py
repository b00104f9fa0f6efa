"""User-facing errors: anything a user can cause raises ``VAError`` with one line saying what is wrong
and how to fix it; the command-line entry points print it and exit with status 2."""

import sys


class VAError(Exception):
    """An error caused by the user's input or options; its message is shown as one line."""


class DataError(VAError):
    """A data folder, image or camera file that cannot be used."""


class ConfigError(VAError, ValueError):
    """An unknown method, preset or option, a value out of range, or inconsistent options (also a
    ``ValueError``)."""


class CheckpointError(VAError):
    """A checkpoint that is missing, corrupt, or belongs to another method."""


def one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings on the command line as ``warning: <message>``, without the source line."""
    print(f"warning: {message}", file=sys.stderr if file is None else file)


def once_each():
    """A ``warnings.showwarning`` like :func:`one_line_warning` that shows each message once: a command
    reads its input again after training (to export the run as its checkpoint holds it), and the data's
    warnings said during training need no second time."""
    shown: set[str] = set()

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        if str(message) not in shown:
            shown.add(str(message))
            one_line_warning(message, category, filename, lineno, file, line)

    return show


class OutputError(VAError):
    """A file of a run that could not be written (a full disk, a read-only folder); what was kept is said."""
