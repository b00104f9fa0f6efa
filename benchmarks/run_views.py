"""The paper's Fig. 5: Chamfer distance of the original and the view-adaptive method at 4, 8, 12, 16 views.

For every scene, view count and backbone, both methods train on the same scene folder (inputs uniform in
azimuth from view 0, the inconsistency drawn with the same seed) and are evaluated the same way. The paper
reports that the adaptive method's gain is largest at 4 views and shrinks as views are added, while the
original improves with more views. Writes into OUT: views.md (CD and PSNR per view count, paired
changes), views.csv/json, views.png (CD and PSNR against the view count), rows.jsonl, scenes/, runs/.

PSNR is measured on each scene's held-out views, which are fewer at more input views (the rig views an
input takes leave the test split; the off-orbit views stay), so compare PSNR across methods, not counts.

    python benchmarks/run_views.py --preset smoke|quick|full [--view-counts 4,8,12,16] [--out DIR]
        [--scenes mug] [--level 2] [--backbones neus,ngp] [--resume]
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from va_plugin.bench.experiment import Experiment, axis_values, paired_axis_rows
from va_plugin.bench.report import axis_table, plot_against, report_sections, write_outputs
from va_plugin.bench.rows import RowSpec
from va_plugin.cli.bench import main as bench_main


def add_arguments(parser) -> None:
    parser.add_argument("--view-counts", default=None, help="comma-separated input view counts (default: the "
                        "preset's, 4,8,12,16; smoke: 4,8)")


def plan(preset, args, sources: list[str]) -> list[RowSpec]:
    return paired_axis_rows("views", preset, args, sources, axis_values(args.view_counts, preset.view_counts),
                            "views")


def report(rows: list[dict[str, Any]], out: Path, meta: dict[str, Any]) -> list[Path]:
    sections = report_sections("Fig. 5: reconstruction error against the number of input views", meta, rows, [
        "## Chamfer distance (mean ± sd over scenes; CD change: adaptive against original, paired by scene)",
        axis_table(rows, "views", "cd", "views:"),
        "The paper (Fig. 5, no numbers given): the adaptive method's gain is largest at 4 views and shrinks "
        "with more views; the original improves distinctly with more views, the adaptive method much less.",
        "## Volume IoU", axis_table(rows, "views", "iou", "views:"),
        "## PSNR on held-out views (the test split shrinks as inputs are added)",
        axis_table(rows, "views", "psnr", "views:")], ("views.png", "CD and PSNR against the number of views"))
    return write_outputs(rows, out, "views", meta, sections, {"views.png": lambda path: plot_against(
        rows, "views", ("cd", "psnr"), path, "Error against the number of input views (mean ± sd over scenes)",
        "input views")})


EXPERIMENT = Experiment("views", "Views (Fig. 5)", __doc__, plan, report, add_arguments, axis_scenes=True,
                        fixed=("views",))


def main(argv=None) -> int:
    return bench_main(EXPERIMENT, argv)


if __name__ == "__main__":
    sys.exit(main())
