"""The paper's Table 1: each backbone with and without view-adaptive training, on the same inputs.

For every scene and backbone (NeuS, InstantNGP) the original method and its view-adaptive variant train
on the same scene folder with the same seed, step budget and overrides, and both are evaluated the same
way. Writes into OUT:

    table1.md        Table 1 (mean ± sd over scenes), paired deltas beside the paper's, per-scene rows
    table1.csv/json  one row per (scene, method); the JSON also holds each run's time curve
    table1_time.png  CD and PSNR against training seconds, from checkpoints along each run
    rows.jsonl       finished rows (what --resume reads); scenes/ (the scene cache) and runs/ (run folders)

    python benchmarks/run_table1.py --preset smoke|quick|full [--out DIR] [--scenes mug,knot,gso:alarm]
        [--level 2] [--views 4] [--backbones neus,ngp] [--data-root ../shared/data/gso] [--resume]
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, Dict, List

from va_plugin.bench.cli import Experiment, adaptive_overrides, backbones_from_args, main as bench_main
from va_plugin.bench.report import (delta_table, header_block, per_scene_table, plot_time_curves, settings_line,
                                    summary_table, write_csv, write_json)
from va_plugin.bench.rows import RowSpec, scene_of

PAPER_TABLE1 = {
    "ngp": {"original": {"psnr": 20.04, "ssim": 0.768, "lpips": 0.159, "cd": 0.0230, "iou": 0.5169},
            "adaptive": {"psnr": 21.89, "ssim": 0.813, "lpips": 0.145, "cd": 0.0142, "iou": 0.6597}},
    "neus": {"original": {"psnr": 19.76, "ssim": 0.790, "lpips": 0.153, "cd": 0.0168, "iou": 0.6268},
             "adaptive": {"psnr": 22.74, "ssim": 0.833, "lpips": 0.130, "cd": 0.0122, "iou": 0.7015}},
}
"""The paper's Table 1 (50 GSO objects, SyncDreamer inputs, RTX 3090)."""


def plan(preset, args, sources: List[str]) -> List[RowSpec]:
    """Per scene and backbone, the original row then the adaptive row (adjacent, so that both see about the
    same load on a shared machine)."""
    rows = []
    for source in sources:
        scene = scene_of(source, preset, args.seed)
        for backbone in backbones_from_args(args):
            rows.append(RowSpec("table1", scene, backbone, adaptive=False))
            rows.append(RowSpec("table1", scene, backbone, adaptive=True, overrides=adaptive_overrides(args)))
    return rows


def report(rows: List[Dict[str, Any]], out: Path, meta: Dict[str, Any]) -> List[Path]:
    scenes = len({r["scene"] for r in rows})
    meta = {**meta, "settings": meta["settings"] + "; " + settings_line(rows)}
    text = "\n\n".join([
        header_block("Table 1: original vs view-adaptive training", meta),
        f"## Mean ± sd over {scenes} scene(s)", summary_table(rows, expected=scenes),
        "## View-adaptive minus original, paired by scene",
        "CD change is relative (negative is better), time ratio is adaptive / original training seconds; "
        "(k/n better) counts the scenes where the adaptive run did better. The paper's deltas are from its "
        "Table 1 (50 GSO objects, SyncDreamer inputs, GPU).",
        delta_table(rows, PAPER_TABLE1),
        "## Per scene", per_scene_table(rows),
        "![CD and PSNR against training seconds](table1_time.png)",
    ])
    md = out / "table1.md"
    md.write_text(text + "\n")
    written = [md, write_csv(rows, out / "table1.csv"), write_json(rows, out / "table1.json", meta)]
    plot = plot_time_curves(rows, out / "table1_time.png", "Error against training time (checkpoints along each run)")
    return written + ([plot] if plot else [])


EXPERIMENT = Experiment("table1", "Table 1", __doc__, plan, report)


def main(argv=None) -> int:
    return bench_main(EXPERIMENT, argv)


if __name__ == "__main__":
    sys.exit(main())
