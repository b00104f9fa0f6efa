"""A batch's state on disk: ``OUT/batch.json`` (the settings every object is run with) and
``OUT/manifest.jsonl`` (one JSON line per finished object, ok or failed).

The manifest is rewritten atomically after each object. ``--resume`` runs only the objects it lacks (and,
with ``--retry-failed``, those that failed), and only with the settings the batch was started with.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from va_plugin.bench.store import _finite_or_none
from va_plugin.errors import ConfigError
from va_plugin.utils.files import write_atomic

SETTINGS_FILE = "batch.json"
MANIFEST_FILE = "manifest.jsonl"


def settings_fingerprint(settings: dict[str, Any]) -> str:
    return hashlib.sha1(json.dumps(settings, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _changes(stored: dict[str, Any], settings: dict[str, Any]) -> list[str]:
    """``key: old -> new`` for each setting that differs (one level into nested dicts)."""
    changes = []
    for key in sorted(set(stored) | set(settings)):
        old, new = stored.get(key), settings.get(key)
        if isinstance(old, dict) and isinstance(new, dict):
            changes += [f"{key}.{c}" for c in _changes(old, new)]
        elif old != new:
            changes.append(f"{key}: {old!r} -> {new!r}")
    return changes


class Manifest:
    """The finished objects of one batch folder."""

    def __init__(self, out: Path, settings: dict[str, Any], resume: bool) -> None:
        self.out = Path(out)
        self.path = self.out / MANIFEST_FILE
        settings = json.loads(json.dumps(settings, default=str))  # as it reads back from disk
        settings_path = self.out / SETTINGS_FILE
        if settings_path.is_file():
            if not resume:
                raise ConfigError(f"{self.out} already holds a batch ({SETTINGS_FILE}); pass --resume to "
                                  "continue it, or choose another --out")
            try:
                stored = json.loads(settings_path.read_text(encoding="utf-8"))["settings"]
            except (ValueError, KeyError, TypeError):
                raise ConfigError(f"{settings_path} is not a va-batch settings file; choose another --out") from None
            changes = _changes(stored, settings)
            if changes:
                raise ConfigError(f"{self.out} was started with other settings ({'; '.join(changes)}); resume it "
                                  "with the same options, or choose another --out")
        else:
            write_atomic(settings_path, json.dumps({"settings": settings,
                                                    "fingerprint": settings_fingerprint(settings)}, indent=2))
        self.records: dict[str, dict[str, Any]] = {}
        if self.path.is_file():
            for line in self.path.read_text(encoding="utf-8").splitlines():
                try:
                    record = json.loads(line)
                except ValueError:
                    continue
                if isinstance(record, dict) and "name" in record:
                    self.records[record["name"]] = record

    def finished(self, name: str, retry_failed: bool = False) -> bool:
        """Whether ``name`` needs no job: it has a record (an ok one, with ``retry_failed``)."""
        record = self.records.get(name)
        return record is not None and (record.get("status") == "ok" or not retry_failed)

    def add(self, record: dict[str, Any]) -> None:
        """Store one finished object's record and rewrite the manifest."""
        self.records[record["name"]] = record
        text = "".join(json.dumps(_finite_or_none(r), sort_keys=True) + "\n" for r in self.records.values())
        write_atomic(self.path, text)
