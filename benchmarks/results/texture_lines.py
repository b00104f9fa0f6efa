"""Reading run_texture.py's output lines (one JSON record a run) for the comparison scripts under
benchmarks/results: one loader and one way of naming the object a run trained on, shared by
crossings/texture_compare.py, texture-sampling/table.py and texture-field-prior/compare.py.

The scripts run as ``python benchmarks/results/X/script.py``; they put this folder on ``sys.path`` first.
"""
import json
import re
import sys
from pathlib import Path
from typing import Dict, List, Optional


def object_name(run: str) -> str:
    """The GSO object of a run folder (``.../gso-bell-l2-v4-r256-s42/neus/neus`` -> ``bell``); the path
    itself for a run not named that way."""
    found = re.search(r"gso-([a-z0-9_]+?)-l\d", run)
    return found.group(1) if found else run


def load(path: str) -> List[dict]:
    """Every record of a run_texture.py output file; exits with one line when the file is missing or a line
    is not JSON (a line cut short by a crash is skipped, as the package's result store does)."""
    file = Path(path)
    if not file.is_file():
        sys.exit(f"{path}: no such file")
    records = []
    for number, line in enumerate(file.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            print(f"{path}:{number}: not a whole JSON line, skipped", file=sys.stderr)
    return records


def by_object(path: str, supersample: Optional[int] = None) -> Dict[str, dict]:
    """The records of ``path`` keyed by object (the last line wins), only those scored at ``supersample``
    rays a side when given (records from before that setting are read as 2, as run_texture.py does)."""
    out = {}
    for record in load(path):
        if supersample is None or record.get("supersample", 2) == supersample:
            out[object_name(record["run"])] = record
    return out
