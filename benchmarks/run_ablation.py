"""The paper's Table 4: cumulative ablation from the original backbone to the full view-adaptive model.

Rows, each adding one component to the one before (the view-adaptive field's switches, all under
``pipeline.model.field.``): Baseline (the original method); + view-adaptive branches (``fusion=false``,
``entropy_weight=0``, ``consistency_weight=0``); + self-attention fusion; + entropy regularization; +
consistency loss (the full model). Every adaptive row forces the adaptive phases
(``skip_consistent_scenes=false``), so no row silently falls back to the baseline. Writes into OUT:
ablation.md (Table 4 with step-by-step changes beside the paper's), ablation.csv/json, ablation_time.png,
rows.jsonl, scenes/, runs/.

    python benchmarks/run_ablation.py --preset smoke|quick|full [--backbones neus] [--out DIR]
        [--scenes mug,knot,chair] [--level 2] [--views 4] [--resume]
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from va_plugin.bench.experiment import Experiment, adaptive_overrides, backbones_from_args
from va_plugin.bench.presets import BACKBONE_TITLES
from va_plugin.bench.report import (
    DELTA_TITLES,
    delta_cell,
    fmt_delta,
    group_rows,
    markdown_table,
    metric_delta,
    plot_time_curves,
    report_sections,
    write_outputs,
)
from va_plugin.bench.rows import RowSpec, scene_of
from va_plugin.cli.bench import main as bench_main

FIELD = "pipeline.model.field."
FORCE = (FIELD + "skip_consistent_scenes=false",)
STEPS = [
    ("Baseline", None),
    ("+ View-adaptive branches", (FIELD + "fusion=false", FIELD + "entropy_weight=0", FIELD + "consistency_weight=0")),
    ("+ Self-attention fusion", (FIELD + "entropy_weight=0", FIELD + "consistency_weight=0")),
    ("+ Entropy regularization", (FIELD + "consistency_weight=0",)),
    ("+ Consistency loss (full model)", ()),
]
"""(row label, overrides of the view-adaptive method; None: the original method)."""

PAPER_TABLE4 = [
    {"psnr": 19.76, "ssim": 0.790, "lpips": 0.153, "cd": 0.0168, "iou": 0.6268},
    {"psnr": 21.94, "ssim": 0.820, "lpips": 0.139, "cd": 0.0136, "iou": 0.6788},
    {"psnr": 22.34, "ssim": 0.827, "lpips": 0.135, "cd": 0.0129, "iou": 0.6902},
    {"psnr": 22.55, "ssim": 0.830, "lpips": 0.132, "cd": 0.0126, "iou": 0.6955},
    {"psnr": 22.74, "ssim": 0.833, "lpips": 0.130, "cd": 0.0122, "iou": 0.7015},
]
"""The paper's Table 4 (NeuS, SyncDreamer inputs), in the order of STEPS."""


def plan(preset, args, sources: list[str]) -> list[RowSpec]:
    rows = []
    for source in sources:
        scene = scene_of(source, preset, args.seed)
        for backbone in backbones_from_args(args):
            title = BACKBONE_TITLES.get(backbone, backbone)
            for label, overrides in STEPS:
                rows.append(RowSpec("ablation", scene, backbone, adaptive=overrides is not None,
                                    variant=f"{title}: {label}",
                                    overrides=() if overrides is None
                                    else FORCE + adaptive_overrides(args) + overrides))
    return rows


def step_table(rows: list[dict[str, Any]]) -> str:
    """Each row label against the one before it, paired by scene, with the paper's step beside it (NeuS)."""
    body = []
    for backbone, group in group_rows(rows, lambda r: r["backbone"]).items():
        by_label = group_rows(group, lambda r: r["variant"])
        labels = list(by_label)
        for i in range(1, len(labels)):
            previous = {r["scene"]: r for r in by_label[labels[i - 1]]}
            pairs = [(previous[r["scene"]], r) for r in by_label[labels[i]] if r["scene"] in previous]
            body.append([f"{labels[i]}, ours", *(delta_cell(m, pairs) for m in DELTA_TITLES)])
            if backbone == "neus" and i < len(PAPER_TABLE4):
                before, after = PAPER_TABLE4[i - 1], PAPER_TABLE4[i]
                body.append([f"{labels[i]}, paper",
                             *(fmt_delta(m, metric_delta(m, before.get(m), after.get(m))) for m in DELTA_TITLES)])
    return markdown_table(["Step (against the row before)", *DELTA_TITLES.values()], body)


def report(rows: list[dict[str, Any]], out: Path, meta: dict[str, Any]) -> list[Path]:
    sections = report_sections("Table 4: cumulative ablation", meta, rows, [
        "## Each step against the row before, paired by scene",
        "The paper's steps are from its Table 4 (NeuS, SyncDreamer inputs, GPU).",
        step_table(rows)], ("ablation_time.png", "CD and PSNR against training seconds"), True)
    return write_outputs(rows, out, "ablation", meta, sections, {"ablation_time.png": lambda path: plot_time_curves(
        rows, path, "Ablation: error against training time")})


EXPERIMENT = Experiment("ablation", "Ablation (Table 4)", __doc__, plan, report, default_backbones="neus")


def main(argv=None) -> int:
    return bench_main(EXPERIMENT, argv)


if __name__ == "__main__":
    sys.exit(main())
