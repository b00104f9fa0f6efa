"""Reading run_texture.py's output lines (one JSON record a run) for the comparison scripts under
benchmarks/results: one loader and one way of naming the object a run trained on, shared by
crossings/texture_compare.py, texture-sampling/table.py and texture-field-prior/compare.py.

The scripts run as ``python benchmarks/results/X/script.py``; they put this folder on ``sys.path`` first.
"""
import re
import sys
from pathlib import Path
from typing import Dict, List, Optional

from va_plugin.bench.store import read_json_lines


def object_name(run: str) -> str:
    """The GSO object of a run folder (``.../gso-bell-l2-v4-r256-s42/neus/neus`` -> ``bell``); the path
    itself for a run not named that way."""
    found = re.search(r"gso-([a-z0-9_]+?)-l\d", run)
    return found.group(1) if found else run


def load(path: str) -> List[dict]:
    """Every record of a run_texture.py output file; exits with one line when the file is missing. A line that
    is not whole JSON (cut short by a crash) is skipped, and how many were is said on stderr."""
    if not Path(path).is_file():
        sys.exit(f"{path}: no such file")
    records, skipped = read_json_lines(Path(path))
    if skipped:
        print(f"{path}: {skipped} line(s) not whole JSON, skipped", file=sys.stderr)
    return records


def by_object(path: str, supersample: Optional[int] = None) -> Dict[str, dict]:
    """The records of ``path`` keyed by object (the last line wins), only those scored at ``supersample``
    rays a side when given (records from before that setting are read as 2, as run_texture.py does)."""
    out = {}
    for record in load(path):
        if supersample is None or record.get("supersample", 2) == supersample:
            out[object_name(record["run"])] = record
    return out
