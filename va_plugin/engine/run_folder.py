"""Run folders that are safe to write: a manifest that marks a folder as a run, a lock against a second
writer, and the check that ``--resume`` continues the same run.

A command writes only into a folder that is new or empty, or that holds a run of its own (its manifest
``va-run.json``, written before anything else, or the checkpoints of a run made before manifests
existed). Any other folder is refused, naming a file found there, unless the user passes ``--overwrite``.
The input is never inside the output folder. While a command writes, ``.va-lock`` names its process; a
second command on the folder is refused with that process's id, and a lock whose process has ended is
taken over with a warning.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import socket
import tempfile
import time
import warnings
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

from va_plugin.config import to_dict
from va_plugin.engine.metrics_log import METRICS_FILE
from va_plugin.engine.trainer import CHECKPOINT_DIR, TrainerConfig, list_checkpoints
from va_plugin.errors import ConfigError, VAError
from va_plugin.utils.files import write_atomic

MANIFEST_FILE = "va-run.json"
LOCK_FILE = ".va-lock"
MANIFEST_VERSION = 1

FREE_TO_CHANGE = ("max_steps", "device", "output_dir", "progress", "num_threads", "checkpoint_every",
                  "keep_checkpoints", "log_every", "eval_every", "eval_views")
"""Trainer options a resumed run may change (a longer budget, another device, other logging)."""


class RunFolderError(ConfigError):
    """An output folder that a command may not write (someone else's files, a folder in use, another run)."""


# -- what the folder holds ------------------------------------------------------------------------------
def check_output_dir(path: Path, flag: str) -> None:
    """Refuse an output folder that cannot be one (a file, or under a file) or cannot be written, before
    any work and without creating anything; ``flag`` is the option's name as the user typed it."""
    path = Path(path).expanduser()
    if path.exists() and not path.is_dir():
        raise RunFolderError(f"{flag} {path} is a file, not a folder; choose another {flag}")
    existing = path
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise RunFolderError(f"{flag} {path} cannot be created: {existing} is a file")
    try:  # os.access alone says yes to root on a read-only mount
        writable = os.access(existing, os.W_OK | os.X_OK)
        if writable:
            tempfile.TemporaryFile(dir=existing).close()
    except OSError:
        writable = False
    if not writable:
        raise RunFolderError(f"{flag} {path} cannot be written: {existing} is read-only for this user")


def has_checkpoints(path: Path) -> bool:
    return bool(list_checkpoints(Path(path)))


def is_run_folder(path: Path) -> bool:
    """Whether ``path`` holds a run of this package (a manifest, or a pre-manifest run's checkpoints)."""
    return (Path(path) / MANIFEST_FILE).is_file() or has_checkpoints(path)


def _foreign_entry(path: Path) -> Path | None:
    """The first entry of ``path`` that is not ours to write over (None for a missing or empty folder)."""
    if not path.is_dir():
        return None
    entries = sorted(p for p in path.iterdir() if p.name != LOCK_FILE)
    return entries[0] if entries else None


def _inside(inner: Path, outer: Path) -> bool:
    inner, outer = inner.resolve(), outer.resolve()
    return inner == outer or outer in inner.parents


def check_writable_folder(path: Path, *, flag: str = "--out", inputs: Iterable[Path] = (),
                          overwrite: bool = False, marker: str | None = None) -> None:
    """Refuse, before any work, an output folder this command may not write: a file, an unwritable
    place, a folder that holds the input, or a non-empty folder that holds no run (without ``overwrite``).
    ``marker``: the file that marks a folder as this command's own instead of a run's manifest."""
    path = Path(path).expanduser()
    check_output_dir(path, flag)
    for source in inputs:
        if source is not None and Path(source).exists() and _inside(Path(source), path):
            raise RunFolderError(f"{flag} {path} holds the input {source}; the outputs would be written among "
                                 f"the input's files: choose another {flag}")
    if overwrite or (is_run_folder(path) if marker is None else (path / marker).is_file()):
        return
    found = _foreign_entry(path)
    if found is not None:
        what = "no run" if marker is None else f"no {marker}"
        raise RunFolderError(f"{flag} {path} is not empty and holds {what} (found {found.name}); choose a new "
                             f"or empty folder, or pass --overwrite to write into it anyway")


# -- the data a run was trained on ------------------------------------------------------------------------
def data_fingerprint(paths: Iterable[Path | None]) -> str:
    """SHA-256 over the files of the inputs (a file, or every non-hidden file under a folder), their
    relative names included, so that another input or an edited one gives another fingerprint."""
    digest = hashlib.sha256()
    for root in paths:
        if root is None:
            continue
        root = Path(root).expanduser()
        files = [root] if root.is_file() else sorted(
            p for p in root.rglob("*") if p.is_file() and not any(part.startswith(".") for part in
                                                                  p.relative_to(root).parts))
        for file in files:
            digest.update(str(file.relative_to(root) if file != root else file.name).encode() + b"\0")
            with open(file, "rb") as handle:
                for block in iter(lambda: handle.read(1 << 20), b""):
                    digest.update(block)
            digest.update(b"\0")
    return digest.hexdigest()


def data_paths(config: TrainerConfig) -> list[Path]:
    """The input files a config trains on: its data and, for generator inputs, a mask folder or image."""
    return [Path(p) for p in config.pipeline.datamanager.dataparser.input_paths().values() if p is not None]


def _flatten(data: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(data, Mapping):
        out: dict[str, Any] = {}
        for key, value in data.items():
            out.update(_flatten(value, f"{prefix}{key}."))
        return out
    return {prefix[:-1]: data}


def comparable_config(config: TrainerConfig) -> dict[str, Any]:
    """The config's values that a resumed run must keep, flat (``pipeline.model.eikonal_weight``)."""
    flat = _flatten(to_dict(config))
    for key in FREE_TO_CHANGE:
        flat.pop(key, None)
    flat.pop("pipeline.datamanager.dataparser.data", None)  # the data is compared by its fingerprint
    flat.pop("pipeline.datamanager.dataparser.masks", None)
    return flat


def make_manifest(config: TrainerConfig, preset: str | None, command: str) -> dict[str, Any]:
    return {"manifest_version": MANIFEST_VERSION, "written_by": command, "method": config.method_name,
            "preset": preset or "default", "data": [str(p) for p in data_paths(config)],
            "data_sha256": data_fingerprint(data_paths(config)), "config": comparable_config(config),
            "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")}


def read_manifest(path: Path) -> dict[str, Any] | None:
    file = Path(path) / MANIFEST_FILE
    if not file.is_file():
        return None
    try:
        with open(file, encoding="utf-8") as handle:
            manifest = json.load(handle)
    except (OSError, ValueError):
        raise RunFolderError(f"{file} cannot be read as a run manifest; move the folder aside or pass "
                             "--overwrite") from None
    if not isinstance(manifest, dict):
        raise RunFolderError(f"{file} is not a run manifest; move the folder aside or pass --overwrite")
    return manifest


def _shown(value: Any) -> str:
    return json.dumps(value) if not isinstance(value, str) else value


def check_same_run(manifest: Mapping[str, Any], current: Mapping[str, Any], folder: Path) -> None:
    """Refuse to resume ``folder`` with another method, preset, input or option than it was made with."""
    def refuse(what: str) -> None:
        raise RunFolderError(f"--resume: {folder} was trained {what}; resume with the options it was made with, "
                             "or choose another output folder")

    if manifest.get("method") != current["method"]:
        refuse(f"with method {manifest.get('method')}, not {current['method']}")
    if manifest.get("preset") != current["preset"]:
        refuse(f"with preset {manifest.get('preset')}, not {current['preset']}")
    if manifest.get("data_sha256") != current["data_sha256"]:
        was = ", ".join(manifest.get("data", [])) or "other data"
        refuse(f"on {was} (other files than {', '.join(current['data'])}: their contents differ)")
    old, new = manifest.get("config", {}), current["config"]
    changed = sorted(key for key in set(old) | set(new) if old.get(key, "<unset>") != new.get(key, "<unset>"))
    if changed:
        key = changed[0]
        more = f" (and {len(changed) - 1} other options)" if len(changed) > 1 else ""
        refuse(f"with {key}={_shown(old.get(key, '<unset>'))}, not {_shown(new.get(key, '<unset>'))}{more}")


# -- the lock ---------------------------------------------------------------------------------------------
def _process_stat(pid: int) -> list[str] | None:
    """The fields of ``/proc/PID/stat`` after the command name (Linux; None elsewhere or when gone)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as handle:
            return handle.read().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None


def _process_start(pid: int) -> str | None:
    """The start time of process ``pid`` in clock ticks since boot, to tell a reused pid apart."""
    stat = _process_stat(pid)
    return stat[19] if stat is not None and len(stat) > 19 else None


def _alive(pid: int, started: str | None) -> bool:
    """Whether process ``pid`` (started at ``started``) still runs: not gone, not a zombie, not a new
    process that reuses its id."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    stat = _process_stat(pid)
    if stat is None:
        return True
    return stat[0] not in ("Z", "X") and (started is None or stat[19] == started)


_held: dict[Path, int] = {}


@contextlib.contextmanager
def folder_lock(path: Path) -> Iterator[None]:
    """Hold ``path/.va-lock`` for the block; refuse when a live process holds it (re-entrant in one process)."""
    path = Path(path).resolve()
    if _held.get(path):
        _held[path] += 1
        try:
            yield
        finally:
            _held[path] -= 1
        return
    path.mkdir(parents=True, exist_ok=True)
    lock = path / LOCK_FILE
    me = {"pid": os.getpid(), "host": socket.gethostname(), "started": _process_start(os.getpid()),
          "since": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                with open(lock, encoding="utf-8") as handle:
                    holder = json.load(handle)
                pid = int(holder["pid"])
            except (OSError, ValueError, KeyError, TypeError):
                holder, pid = {}, -1
            if pid > 0 and holder.get("host") == me["host"] and _alive(pid, holder.get("started")):
                raise RunFolderError(f"{path} is in use by process {pid} (since {holder.get('since', '?')}); "
                                     "wait for it to end, or choose another output folder") from None
            if pid > 0 and holder.get("host") not in (None, me["host"]):
                raise RunFolderError(f"{path} is in use by process {pid} on {holder['host']}; wait for it to "
                                     f"end, or delete {lock} if that run is over") from None
            warnings.warn(f"{path}: taking over the lock of process {pid if pid > 0 else '?'}, which is no "
                          "longer running", stacklevel=3)
            lock.unlink(missing_ok=True)
            continue
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            json.dump(me, handle)
        break
    _held[path] = 1
    try:
        yield
    finally:
        del _held[path]
        with contextlib.suppress(OSError):  # a folder gone read-only: the next run takes the stale lock over
            lock.unlink(missing_ok=True)


# -- a run's folder, claimed --------------------------------------------------------------------------------
def _clear_previous_run(path: Path) -> None:
    """With ``--overwrite`` and no ``--resume``: drop an earlier run's checkpoints and log, so the new run
    does not continue or mix with them (other files are overwritten as they are written)."""
    shutil.rmtree(path / CHECKPOINT_DIR, ignore_errors=True)
    (path / METRICS_FILE).unlink(missing_ok=True)
    (path / MANIFEST_FILE).unlink(missing_ok=True)


@contextlib.contextmanager
def _removed_on_error(folder: Path | None, existed: bool) -> Iterator[None]:
    """Take back what a run wrote into ``folder`` (new, or empty before it if ``existed``) when a user error
    stops it before its first checkpoint: bad input leaves nothing behind."""
    try:
        yield
    except VAError:
        if folder is not None and folder.is_dir() and not has_checkpoints(folder):
            for entry in folder.iterdir():
                if entry.name != LOCK_FILE:
                    shutil.rmtree(entry) if entry.is_dir() else entry.unlink(missing_ok=True)
            if not existed:
                shutil.rmtree(folder, ignore_errors=True)
        raise


@contextlib.contextmanager
def claim_run_folder(config: TrainerConfig, *, resume: bool = False, overwrite: bool = False,
                     preset: str | None = None, command: str = "train", flag: str = "--out") -> Iterator[bool]:
    """Check and lock ``config.output_dir`` for training, write its manifest first, and yield whether
    the run continues from a checkpoint. Refuses (nothing written): a folder this command may not write
    (:func:`check_writable_folder`), a run there without ``resume`` (or ``overwrite``), a run there on
    another input (without ``overwrite``, checkpoints or not), ``resume`` of a folder with nothing to
    resume, and ``resume`` with another method, preset, input or option."""
    folder = Path(config.output_dir).expanduser()
    check_writable_folder(folder, flag=flag, inputs=data_paths(config), overwrite=overwrite)
    current = make_manifest(config, preset, command)
    existed = folder.exists()
    fresh = not existed or _foreign_entry(folder) is None
    with folder_lock(folder), _removed_on_error(folder if fresh else None, existed):
        manifest = read_manifest(folder) if not (overwrite and not resume) else None
        continues = has_checkpoints(folder)
        other_input = manifest is not None and manifest.get("data_sha256") != current["data_sha256"]
        if other_input and not overwrite and not (resume and continues):  # a resume: check_same_run says it
            was = ", ".join(manifest.get("data", [])) or "other data"
            raise RunFolderError(f"{folder} holds a run on {was}, not on {', '.join(current['data'])} (their files "
                                 f"differ); pass --overwrite to replace that run, or choose another {flag}")
        if resume and not continues:
            if manifest is None and _foreign_entry(folder) is None:
                warnings.warn(f"--resume: {folder} holds no run yet; starting a new one", stacklevel=3)
        elif continues and not resume:
            if not overwrite:
                raise RunFolderError(f"{folder} already holds a run; pass --resume to continue it, --overwrite "
                                     f"to start it again, or choose another {flag}")
            _clear_previous_run(folder)
            continues = False
        if continues and manifest is not None:
            check_same_run(manifest, current, folder)
        if manifest is None or not continues:
            write_atomic(folder / MANIFEST_FILE, json.dumps(current, indent=2))
        yield continues


@contextlib.contextmanager
def writing_into_run(folder: Path) -> Iterator[None]:
    """Lock a run folder while a command (an export, an evaluation) writes into it."""
    folder = Path(folder).expanduser()
    if not folder.is_dir():
        yield
        return
    with folder_lock(folder):
        yield


def check_output_file(path: Path, run_dir: Path | None = None, overwrite: bool = False,
                      flag: str = "--output") -> None:
    """Refuse, before any work, an output file whose folder cannot be written, and an existing file outside
    a run folder without ``overwrite``."""
    path = Path(path).expanduser()
    check_output_dir(path.parent, flag)
    if not path.exists() or overwrite:
        return
    if path.is_dir():
        raise RunFolderError(f"{flag} {path} is a folder; give a file name")
    if run_dir is not None and _inside(path.parent, Path(run_dir)) and is_run_folder(run_dir):
        return
    if is_run_folder(path.parent):
        return
    raise ConfigError(f"{flag} {path} exists; pass --overwrite to replace it, or choose another file name")
