"""The command line of the recovery scripts (``bench_camera_recovery.py``, ``bench_warp_recovery.py``): run
folders in, one figure set per run printed (and optionally written as JSON), one error line and exit 2
for a folder that is not the kind of run the script reads."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional

from va_plugin.errors import VAError


def recovery_main(description: str, recovery: Callable[[Path], Dict[str, Any]],
                  show: Callable[[Dict[str, Any]], None], argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("runs", nargs="+", type=Path, help="run folders")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args(argv)
    try:
        results = [recovery(run) for run in args.runs]
    except (VAError, OSError, KeyError, json.JSONDecodeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for result in results:
        show(result)
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=2))
    return 0
