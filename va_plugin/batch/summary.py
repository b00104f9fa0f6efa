"""A batch's reports: ``summary.csv`` (one row per object), ``summary.md`` (the same table with means)
and ``contact_sheet.png`` (every object's mesh thumbnail, captioned with its name)."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from va_plugin.batch.job import METRICS
from va_plugin.bench.report import markdown_table
from va_plugin.data.images import read_image, write_image
from va_plugin.utils.files import write_atomic

COLUMNS = ("name", "status", "seconds", *METRICS, "steps", "train_seconds", "error", "input", "run_dir")
MEAN_COLUMNS = ("seconds", *METRICS, "steps", "train_seconds")
CAPTION_PX = 16


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return "" if not math.isfinite(value) else f"{value:.6g}"
    return str(value)


def summary_rows(records: Sequence[dict[str, Any]]) -> list[dict[str, str]]:
    """Each record's summary columns as text, empty where it has no value (no ground truth, failed)."""
    return [{column: _cell(record.get(column)) for column in COLUMNS} for record in records]


def _short(text: str, limit: int = 160) -> str:
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _means(records: Sequence[dict[str, Any]]) -> dict[str, float | None]:
    """The mean of each numeric column over the objects that finished and have it."""
    means: dict[str, float | None] = {}
    for column in MEAN_COLUMNS:
        values = [float(r[column]) for r in records
                  if r.get("status") == "ok" and isinstance(r.get(column), (int, float))
                  and math.isfinite(float(r[column]))]
        means[column] = float(np.mean(values)) if values else None
    return means


def write_summary(out: Path, records: Sequence[dict[str, Any]], title: str = "va-batch") -> list[Path]:
    """``OUT/summary.csv`` and ``OUT/summary.md`` of ``records`` (in the given order)."""
    rows = summary_rows(records)
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    csv_path = write_atomic(Path(out) / "summary.csv", text.getvalue())

    shown = [c for c in COLUMNS if c not in ("input", "run_dir")]
    failed = sum(r.get("status") != "ok" for r in records)
    means = _means(records)
    body = [[_short(row[c]).replace("|", "\\|") for c in shown] for row in rows]
    body.append([f"**mean** ({len(records) - failed} ok)", "", *[_cell(means.get(c)) for c in shown[2:]]])
    md = [f"# {title}", "", f"{len(records)} objects: {len(records) - failed} ok, {failed} failed. Metrics are empty "
          "where an object has no ground truth (generator outputs) or failed; means are over the objects that "
          "have the value.", "", markdown_table(shown, body), ""]
    md_path = write_atomic(Path(out) / "summary.md", "\n".join(md))
    return [csv_path, md_path]


def _caption(tile: np.ndarray, text: str, failed: bool) -> np.ndarray:
    import cv2

    band = np.full((CAPTION_PX, tile.shape[1], 3), 255, np.uint8)
    color = (200, 0, 0) if failed else (0, 0, 0)
    cv2.putText(band, text, (3, CAPTION_PX - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.35, color, 1, cv2.LINE_AA)
    return np.concatenate([band, tile], axis=0)


def contact_sheet(out: Path, records: Sequence[dict[str, Any]], columns: int = 4) -> Path | None:
    """``OUT/contact_sheet.png``: each object's thumbnail under its name (a grey tile for one without a
    mesh), ``columns`` objects a row; None when no object has a thumbnail."""
    import cv2


    thumbs = {}
    for record in records:
        path = record.get("thumbnail")
        if path and Path(path).is_file():
            thumbs[record["name"]] = (read_image(Path(path))[..., :3] * 255).astype(np.uint8)
    if not thumbs:
        return None
    height, width = next(iter(thumbs.values())).shape[:2]
    tiles = []
    for record in records:
        tile = thumbs.get(record["name"])
        if tile is None:
            tile = np.full((height, width, 3), 170, np.uint8)
        elif tile.shape[:2] != (height, width):
            tile = cv2.resize(tile, (width, height), interpolation=cv2.INTER_AREA)
        failed = record.get("status") != "ok"
        label = record["name"] + (" (failed)" if failed else "")
        tiles.append(_caption(tile, label, failed))
    columns = max(1, min(columns, len(tiles)))
    tiles += [np.full_like(tiles[0], 255)] * (-len(tiles) % columns)
    rows = [np.concatenate(tiles[i:i + columns], axis=1) for i in range(0, len(tiles), columns)]
    path = Path(out) / "contact_sheet.png"
    write_image(path, np.concatenate(rows, axis=0))
    return path
