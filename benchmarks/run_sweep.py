"""Error against inconsistency level 0..3 for the original and the view-adaptive method: a test of the
paper's Lemma 1 and Theorem 1.

Lemma 1 bounds the error of an averaging reconstruction by the mean per-view error (1/n) sum ||delta_i||;
Theorem 1 says view-adaptive learning shrinks it by a factor (1 - lambda_adapt) < 1. So, with the measured
size of the injected errors on the x axis, the original method's error should grow with it and the
adaptive method's should grow more slowly. The x value of a scene is the mean over all its input views of
the RMS color error of the input against its clean render (the clean view 0 counting 0), from the scene
builder's measurements in scene.json. For every scene and backbone, the error's slope against it is fitted
by least squares over the levels; the report gives the slopes of both methods (mean ± sd over scenes),
their ratio (the theorem's 1 - lambda_adapt, if it holds) and a plain verdict, for the Chamfer distance and
for the RMS error of the held-out renders.

Level 0 scenes are consistent: with the method's default ``skip_consistent_scenes`` the adaptive method
may skip its adaptive phases there (``--force-adaptive`` runs them). Writes into OUT: sweep.md,
sweep.csv/json, sweep.png (CD and PSNR against the input error, with fitted lines), rows.jsonl, scenes/, runs/.

    python benchmarks/run_sweep.py --preset smoke|quick|full [--levels 0,1,2,3] [--out DIR] [--scenes mug]
        [--views 4] [--backbones neus,ngp] [--resume]
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

from va_plugin.bench.experiment import Experiment, axis_values, paired_axis_rows
from va_plugin.bench.presets import BACKBONE_TITLES
from va_plugin.bench.report import (
    axis_table,
    fmt,
    fmt_mean_sd,
    group_rows,
    linear_fit,
    markdown_table,
    mean_sd,
    plot_against,
    report_sections,
    write_outputs,
)
from va_plugin.bench.rows import RowSpec
from va_plugin.cli.bench import main as bench_main


def add_arguments(parser) -> None:
    parser.add_argument("--levels", default=None, help="comma-separated inconsistency levels (default: the "
                        "preset's, 0,1,2,3; smoke: 0,2)")


def plan(preset, args, sources: list[str]) -> list[RowSpec]:
    return paired_axis_rows("sweep", preset, args, sources, axis_values(args.levels, preset.levels), "level")


def render_rmse(row: dict[str, Any]) -> float:
    """RMS color error of the held-out renders, from their PSNR: 10^(-PSNR/20)."""
    psnr = row.get("psnr")
    return 10.0 ** (-float(psnr) / 20.0) if psnr is not None and math.isfinite(psnr) else float("nan")


ERRORS = {"cd": ("Chamfer distance", lambda r: r.get("cd")), "render_rmse": ("held-out render RMSE", render_rmse)}


def scene_slopes(group: list[dict[str, Any]], error) -> list[float]:
    """Per scene, the least-squares slope of ``error(row)`` against the input error over the levels."""
    slopes = []
    for rows in group_rows(group, lambda r: r["scene"]).values():
        line = linear_fit([r["input_rmse"] for r in rows], [error(r) for r in rows])
        if line is not None:
            slopes.append(line[0])
    return slopes


def verdict(original: list[float], adaptive: list[float]) -> list[str]:
    (mo, _, no), (ma, _, na) = mean_sd(original), mean_sd(adaptive)
    if not no or not na:
        return ["n/a (needs at least two levels per scene)"] * 3
    lower = f"{sum(a < o for o, a in zip(original, adaptive))}/{min(no, na)} scenes"
    if mo <= 0:  # no growth to slow down: the ratio would mean nothing
        return [f"no: slope {fmt(mo, 'cd')}", "n/a (the original's error does not grow)", lower]
    theorem = "yes" if ma < mo else "no"
    return [f"yes: slope {fmt(mo, 'cd')}", f"{theorem}: ratio adaptive/original {ma / mo:.2f}", lower]


def claims_table(rows: list[dict[str, Any]]) -> str:
    body = []
    for backbone, group in group_rows(rows, lambda r: r["backbone"]).items():
        for title, error in ERRORS.values():
            original = scene_slopes([r for r in group if not r["adaptive"]], error)
            adaptive = scene_slopes([r for r in group if r["adaptive"]], error)
            body.append([BACKBONE_TITLES.get(backbone, backbone), title, fmt_mean_sd(original, "cd"),
                         fmt_mean_sd(adaptive, "cd"), *verdict(original, adaptive)])
    return markdown_table(["Backbone", "error", "slope, original", "slope, adaptive",
                           "Lemma 1: original grows with input error?", "Theorem 1: adaptive grows more slowly?",
                           "adaptive slope lower on"], body)


def input_error_table(rows: list[dict[str, Any]]) -> str:
    body = []
    for level, group in group_rows(sorted(rows, key=lambda r: r["level"]), lambda r: r["level"]).items():
        per_scene = {r["scene"]: r for r in group}.values()
        body.append([level, fmt_mean_sd([r["input_psnr"] for r in per_scene], "input_psnr"),
                     fmt_mean_sd([r["input_rmse"] for r in per_scene], "input_rmse")])
    return markdown_table(["level", "input PSNR dB (perturbed views)", "mean per-view RMSE (x axis)"], body)


def report(rows: list[dict[str, Any]], out: Path, meta: dict[str, Any]) -> list[Path]:
    sections = report_sections("Error against the size of the view inconsistency (Lemma 1, Theorem 1)", meta, rows, [
        "## Measured input error per level (mean ± sd over scenes)", input_error_table(rows),
        "## Lemma 1 and Theorem 1",
        "Slopes are least-squares fits per scene of the error against the mean per-view input RMSE, "
        "over the levels (mean ± sd over scenes). The ratio of the adaptive slope to the original's is "
        "the theorem's 1 - lambda_adapt if the theorem holds: it should lie between 0 and 1.",
        claims_table(rows),
        "## Chamfer distance per level", axis_table(rows, "level", "cd", "level"),
        "## PSNR per level", axis_table(rows, "level", "psnr", "level")],
        ("sweep.png", "CD and PSNR against the input error"))
    return write_outputs(rows, out, "sweep", meta, sections, {"sweep.png": lambda path: plot_against(
        rows, "input_rmse", ("cd", "psnr"), path, "Error against the measured input error (all scenes and levels; "
        "lines: least squares)", "mean per-view input RMSE", fits=True)})


EXPERIMENT = Experiment("sweep", "Inconsistency sweep (Lemma 1, Theorem 1)", __doc__, plan, report, add_arguments,
                        axis_scenes=True, fixed=("level",))


def main(argv: list[str] | None = None) -> int:
    return bench_main(EXPERIMENT, argv)


if __name__ == "__main__":
    sys.exit(main())
