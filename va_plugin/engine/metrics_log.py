"""A run's metrics log, ``RUN/metrics.jsonl``: one JSON object a line, appended by the trainer.

Training records carry ``step`` (steps done), ``loss`` and the loss terms, PSNR and diagnostics; events
carry ``step`` and ``event``; periodic evaluations ``step`` and their metrics."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from va_plugin.utils.files import write_atomic

METRICS_FILE = "metrics.jsonl"


def append_record(run_dir: Path, record: dict[str, Any]) -> None:
    """Append one record to the run's log (the folder is made when missing)."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    with open(run_dir / METRICS_FILE, "a", encoding="utf-8") as handle:
        handle.write(json.dumps(record) + "\n")


def read_records(run_dir: Path) -> list[dict[str, Any]]:
    """The run's records in order; [] without a log. A line that is not a JSON object (cut short by a
    kill) is skipped."""
    path = Path(run_dir) / METRICS_FILE
    if not path.is_file():
        return []
    records = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            record = json.loads(line)
        except ValueError:
            continue
        if isinstance(record, dict):
            records.append(record)
    return records


def training_records(run_dir: Path) -> list[dict[str, Any]]:
    """The records of training steps (those with a ``loss``), in order."""
    return [record for record in read_records(run_dir) if "loss" in record]


def write_records(run_dir: Path, records: list[dict[str, Any]]) -> None:
    """Replace the run's log with ``records`` (a temporary file, then a rename; none left on failure)."""
    write_atomic(Path(run_dir) / METRICS_FILE, "".join(json.dumps(record) + "\n" for record in records))
