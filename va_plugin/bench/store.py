"""Finished benchmark rows on disk: ``OUT/rows.jsonl``, one JSON line per row, appended when a row ends.

A line is flushed to disk in one go. ``--resume`` skips every planned row whose key and settings
fingerprint match a stored line (a row whose settings changed runs again).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Hashable
from pathlib import Path
from typing import Any

from va_plugin.errors import ConfigError

ROWS_FILE = "rows.jsonl"


def read_json_lines(path: Path) -> tuple[list[Any], int]:
    """Every whole JSON line of ``path`` in order, and how many lines were skipped as not whole JSON (a line
    cut short by a crash); blank lines are neither."""
    records: list[Any] = []
    skipped = 0
    for line in Path(path).read_text().splitlines():
        if not line.strip():
            continue
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            skipped += 1
    return records, skipped


def keyed_rows(path: Path, key: Callable[[dict[str, Any]], Hashable]) -> dict[Hashable, dict[str, Any]]:
    """The rows of a JSON-lines file by ``key(row)`` (a later line replaces an earlier one with its key);
    empty when there is no file. A script that appends rows as it goes resumes from these."""
    path = Path(path)
    if not path.is_file():
        return {}
    return {key(row): row for row in read_json_lines(path)[0] if isinstance(row, dict)}


def append_row(path: Path, row: dict[str, Any]) -> None:
    """Append ``row`` to a JSON-lines file as one line, flushed to disk (NaN written as null)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a", encoding="utf-8") as handle:
        handle.write(json.dumps(_finite_or_none(row)) + "\n")
        handle.flush()
        os.fsync(handle.fileno())


def _finite_or_none(value: Any) -> Any:
    """JSON has no NaN: not-a-number metrics are written as null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite_or_none(v) for v in value]
    return value


def _nan_for_none(row: dict[str, Any]) -> dict[str, Any]:
    return {k: (float("nan") if v is None else v) for k, v in row.items()}


class ResultStore:
    """The rows of one benchmark folder."""

    def __init__(self, out: Path, resume: bool) -> None:
        self.path = Path(out) / ROWS_FILE
        self.rows: dict[str, dict[str, Any]] = {}
        if self.path.is_file() and self.path.stat().st_size > 0:
            if not resume:
                raise ConfigError(f"{out} already holds benchmark rows ({ROWS_FILE}); pass --resume to skip "
                                  "the finished ones, or choose another --out")
            for row in read_json_lines(self.path)[0]:
                if isinstance(row, dict) and "key" in row:
                    self.rows[row["key"]] = _nan_for_none(row)

    def finished(self, key: str, fingerprint: str) -> dict[str, Any] | None:
        """The stored row of ``key`` when it was run with the same settings, else None."""
        row = self.rows.get(key)
        return row if row is not None and row.get("fingerprint") == fingerprint else None

    def add(self, row: dict[str, Any]) -> None:
        append_row(self.path, row)
        self.rows[row["key"]] = row
