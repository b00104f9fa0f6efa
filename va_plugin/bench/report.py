"""Writing benchmark results: CSV and JSON rows, Markdown tables (mean and spread over scenes), plots.

Spread is the sample standard deviation over scenes (``± sd``); paired deltas compare the view-adaptive
row with the original row of the same backbone on the same scene (same inputs and seed).
"""

from __future__ import annotations

import csv
import json
import math
import os
import platform
from collections import OrderedDict
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from va_plugin.bench.presets import BACKBONE_TITLES
from va_plugin.bench.store import _finite_or_none

FIELDS = ("scene", "method", "backbone", "adaptive", "psnr", "ssim", "lpips", "cd", "iou", "fscore",
          "train_seconds", "steps")
"""The columns every row has."""
EXTRA_FIELDS = ("variant", "level", "views", "seed", "adaptive_ran", "input_psnr", "input_rmse", "eval_seconds")
"""Further columns: the row's label, the scene's settings and measured input error, evaluation time."""

METRIC_TITLES = OrderedDict([("psnr", "PSNR ↑"), ("ssim", "SSIM ↑"), ("lpips", "LPIPS ↓"), ("cd", "CD ↓"),
                             ("iou", "IoU ↑"), ("fscore", "F@0.02 ↑"), ("train_seconds", "train s")])
DIGITS = {"psnr": 2, "ssim": 3, "lpips": 3, "cd": 4, "iou": 3, "fscore": 3, "train_seconds": 0,
          "input_psnr": 2, "input_rmse": 4}
LOWER_IS_BETTER = {"lpips", "cd", "train_seconds"}


# -- numbers ---------------------------------------------------------------------------------------------
def finite(values: Iterable[Any]) -> list[float]:
    return [float(v) for v in values if v is not None and isinstance(v, (int, float)) and math.isfinite(v)]


def mean_sd(values: Iterable[Any]) -> tuple[float, float, int]:
    """Mean, sample standard deviation (0 for a single value) and count of the finite values."""
    vals = finite(values)
    if not vals:
        return float("nan"), float("nan"), 0
    mean = math.fsum(vals) / len(vals)
    sd = math.sqrt(math.fsum((v - mean) ** 2 for v in vals) / (len(vals) - 1)) if len(vals) > 1 else 0.0
    return mean, sd, len(vals)


def fmt(value: Any, metric: str, signed: bool = False) -> str:
    if value is None or not math.isfinite(float(value)):
        return "n/a"
    return f"{float(value):{'+' if signed else ''}.{DIGITS.get(metric, 3)}f}"


def fmt_mean_sd(values: Iterable[Any], metric: str, expected: int | None = None) -> str:
    mean, sd, n = mean_sd(values)
    if n == 0:
        return "n/a"
    text = f"{fmt(mean, metric)} ± {fmt(sd, metric)}" if n > 1 else fmt(mean, metric)
    return text + (f" ({n}/{expected})" if expected is not None and n < expected else "")


def group_rows(rows: Sequence[dict[str, Any]], key: Callable[[dict[str, Any]], Any]) -> OrderedDict[Any, list]:
    """Rows grouped by ``key``, groups in order of first appearance."""
    groups: OrderedDict[Any, list] = OrderedDict()
    for row in rows:
        groups.setdefault(key(row), []).append(row)
    return groups


# -- files -----------------------------------------------------------------------------------------------
def write_csv(rows: Sequence[dict[str, Any]], path: Path) -> Path:
    columns = FIELDS + EXTRA_FIELDS
    with open(path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(columns)
        for row in rows:
            writer.writerow([_csv_value(row.get(c)) for c in columns])
    return path


def _csv_value(value: Any) -> Any:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if not math.isfinite(value) else repr(round(value, 6))
    return value


def write_json(rows: Sequence[dict[str, Any]], path: Path, meta: dict[str, Any]) -> Path:
    """``{"meta": ..., "rows": [...]}``; each row carries its evaluation settings and its time curve."""
    path.write_text(json.dumps(_finite_or_none({"meta": meta, "rows": list(rows)}), indent=1))
    return path


def machine_info() -> dict[str, Any]:
    import torch

    info: dict[str, Any] = {"platform": platform.platform(), "cpus": os.cpu_count(),
                            "torch": torch.__version__, "torch_threads": torch.get_num_threads(),
                            "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None}
    if hasattr(os, "getloadavg"):
        info["load_average"] = [round(x, 2) for x in os.getloadavg()]
    return info


# -- Markdown --------------------------------------------------------------------------------------------
def markdown_table(header: Sequence[str], body: Iterable[Sequence[Any]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in line) + " |" for line in body]
    return "\n".join(lines)


def header_block(title: str, meta: dict[str, Any], rows: Sequence[dict[str, Any]]) -> str:
    """Title, command, date, machine and settings (the run's and the rows' evaluation) of a report."""
    machine = meta["machine"]
    load = machine.get("load_average_start")
    jobs = meta.get("jobs", 1)
    lines = [f"# {title}", "",
             f"- command: `{meta['command']}`",
             f"- date: {meta['date']}; preset `{meta['preset']}`: {meta['preset_description']}",
             f"- machine: {machine['cpus']} CPU cores, torch {machine['torch']} with {machine['torch_threads']} "
             f"threads{'' if not machine.get('cuda') else ', ' + machine['cuda']}"
             + (f"; {jobs} rows at a time, each in its own process with those threads (train seconds were "
                f"measured with {jobs} rows training at once)" if jobs > 1 else "")
             + (f"; load average {load[0]} at the start, {machine.get('load_average_end', ['?'])[0]} at the end"
                if load else ""),
             f"- {meta['settings']}; {settings_line(rows)}",
             f"- rows: {meta['rows_done']} of {meta['rows_planned']} finished; {meta['rows_run']} run in the last "
             f"session, wall time {meta['wall']}"]
    return "\n".join(lines)


def summary_table(rows: Sequence[dict[str, Any]], expected: int | None = None) -> str:
    """One line per row label (method or variant): mean ± sd over scenes of every metric."""
    body = []
    for label, group in group_rows(rows, lambda r: r["variant"]).items():
        body.append([label, *(fmt_mean_sd([r.get(m) for r in group], m, expected) for m in METRIC_TITLES)])
    return markdown_table(["Method", *METRIC_TITLES.values()], body)


def paired(rows: Sequence[dict[str, Any]], key: Callable[[dict[str, Any]], Any] = lambda r: r["backbone"]
           ) -> OrderedDict[Any, list[tuple[dict, dict]]]:
    """(original, adaptive) row pairs on the same scene, level and views, grouped by ``key``."""
    pairs: OrderedDict[Any, list[tuple[dict, dict]]] = OrderedDict()
    for group in group_rows(rows, lambda r: (key(r), r["scene"], r["level"], r["views"])).values():
        originals = [r for r in group if not r["adaptive"]]
        adaptives = [r for r in group if r["adaptive"]]
        if originals and adaptives:
            pairs.setdefault(key(group[0]), []).append((originals[0], adaptives[0]))
    return pairs


def metric_delta(metric: str, original: Any, adaptive: Any) -> float:
    """Adaptive against original: relative change in % for CD, a ratio for time, a difference otherwise."""
    if not finite([original, adaptive]) or len(finite([original, adaptive])) < 2:
        return float("nan")
    original, adaptive = float(original), float(adaptive)
    if metric == "cd":
        return 100.0 * (adaptive - original) / original if original else float("nan")
    if metric == "train_seconds":
        return adaptive / original if original else float("nan")
    return adaptive - original


def improved(metric: str, delta: float) -> bool:
    """Better by more than the printed precision (a change that prints as 0 is no win)."""
    if metric == "train_seconds":
        return delta < 0.995
    tolerance = 0.5 if metric == "cd" else 0.5 * 10.0 ** -DIGITS.get(metric, 3)
    return delta < -tolerance if metric in LOWER_IS_BETTER else delta > tolerance


def fmt_delta(metric: str, value: float) -> str:
    if not math.isfinite(value):
        return "n/a"
    if metric == "cd":
        return f"{value:+.0f}%"
    if metric == "train_seconds":
        return f"{value:.2f}x"
    return fmt(value, metric, signed=True)


def delta_cell(metric: str, pairs: Sequence[tuple[dict, dict]]) -> str:
    """Mean ± sd over pairs of the paired delta, and on how many pairs the adaptive row did better."""
    deltas = [metric_delta(metric, o.get(metric), a.get(metric)) for o, a in pairs]
    mean, sd, n = mean_sd(deltas)
    if n == 0:
        return "n/a"
    spread = f" ± {fmt_delta(metric, sd).lstrip('+')}" if n > 1 else ""
    if metric == "train_seconds":
        return f"{fmt_delta(metric, mean)}{spread}"
    wins = sum(improved(metric, d) for d in finite(deltas))
    return f"{fmt_delta(metric, mean)}{spread} ({wins}/{n} better)"


DELTA_TITLES = OrderedDict([("psnr", "ΔPSNR dB"), ("ssim", "ΔSSIM"), ("lpips", "ΔLPIPS"), ("cd", "CD change"),
                            ("iou", "ΔIoU"), ("fscore", "ΔF@0.02"), ("train_seconds", "time ratio")])


def delta_table(rows: Sequence[dict[str, Any]], paper: dict[str, dict[str, float]] | None = None) -> str:
    """Per backbone: adaptive minus original, paired by scene; with the paper's deltas when given
    (``paper[backbone] = {"original": {...}, "adaptive": {...}}`` in the paper's table's units)."""
    body = []
    for backbone, pairs in paired(rows).items():
        title = BACKBONE_TITLES.get(backbone, backbone)
        body.append([f"{title}, ours ({len(pairs)} scenes)", *(delta_cell(m, pairs) for m in DELTA_TITLES)])
        if paper and backbone in paper:
            ref = paper[backbone]
            body.append([f"{title}, paper (Table 1)",
                         *(fmt_delta(m, metric_delta(m, ref["original"].get(m), ref["adaptive"].get(m)))
                           for m in DELTA_TITLES)])
    return markdown_table(["Backbone", *DELTA_TITLES.values()], body)


def axis_table(rows: Sequence[dict[str, Any]], axis: str, metric: str, axis_title: str) -> str:
    """``metric`` (mean ± sd over scenes) per row label and value of ``axis`` (views, level), plus per
    backbone the paired change of the adaptive method at each value."""
    values = sorted({r[axis] for r in rows})
    body = []
    for label, group in group_rows(rows, lambda r: r["variant"]).items():
        body.append([label, *(fmt_mean_sd([r.get(metric) for r in group if r[axis] == v], metric) for v in values)])
    for backbone, pairs in paired(rows).items():
        body.append([f"{BACKBONE_TITLES.get(backbone, backbone)}: {DELTA_TITLES[metric]}",
                     *(delta_cell(metric, [p for p in pairs if p[0][axis] == v]) for v in values)])
    return markdown_table([METRIC_TITLES[metric], *(f"{axis_title} {v}" for v in values)], body)


def per_scene_table(rows: Sequence[dict[str, Any]]) -> str:
    body = [[r["scene"], r["level"], r["views"], r["variant"], *(fmt(r.get(m), m) for m in METRIC_TITLES),
             r["steps"], "yes" if r.get("adaptive_ran") else "no"] for r in rows]
    return markdown_table(["scene", "level", "views", "method", *METRIC_TITLES.values(), "steps",
                           "adaptive phases ran"], body)


def settings_line(rows: Sequence[dict[str, Any]]) -> str:
    """Evaluation settings as recorded in the rows (the first row's; all rows of a run share them)."""
    if not rows:
        return "evaluation: no rows yet"
    ev = rows[0].get("evaluation", {})
    image, geo = ev.get("image_params", {}), ev.get("geometry_params", {})
    parts = []
    if image:
        parts.append(f"images: {image.get('views')} held-out views at {image.get('width')} px")
    if geo:
        parts.append(f"meshes: marching cubes {geo.get('mesh_resolution')}^3, CD/F-score on {geo.get('n_samples')} "
                     f"surface samples, F at {geo.get('threshold')}, IoU on a {geo.get('resolution')}^3 grid")
    return "evaluation: " + "; ".join(parts)


def report_sections(title: str, meta: dict[str, Any], rows: Sequence[dict[str, Any]], body: Sequence[str],
                    image: tuple[str, str], with_summary: bool = False) -> list[str]:
    """A report's Markdown sections: the header, (the mean ± sd table,) ``body``, the per-scene rows and
    the plot (``image``: file name, caption)."""
    sections = [header_block(title, meta, rows)]
    if with_summary:
        scenes = len({r["scene"] for r in rows})
        sections += [f"## Mean ± sd over {scenes} scene(s)", summary_table(rows, expected=scenes)]
    return sections + list(body) + ["## Per scene", per_scene_table(rows), f"![{image[1]}]({image[0]})"]


def write_outputs(rows: Sequence[dict[str, Any]], out: Path, name: str, meta: dict[str, Any], sections: Sequence[str],
                  plots: dict[str, Callable[[Path], Path | None]]) -> list[Path]:
    """``OUT/<name>.md`` (the sections), ``.csv``, ``.json`` and the plots (file name -> writer)."""
    md = out / f"{name}.md"
    md.write_text("\n\n".join(sections) + "\n")
    written = [md, write_csv(rows, out / f"{name}.csv"), write_json(rows, out / f"{name}.json", meta)]
    for filename, plot in plots.items():
        path = plot(out / filename)
        if path is not None:
            written.append(path)
    return written


# -- plots -----------------------------------------------------------------------------------------------
def _pyplot():
    """matplotlib's pyplot on the Agg backend, or None (with a note) when the plots extra is missing."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("note: matplotlib is missing (pip install -e .[plots]); no plot written", flush=True)
        return None
    return plt


COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf")


def plot_time_curves(rows: Sequence[dict[str, Any]], path: Path, title: str) -> Path | None:
    """CD and PSNR against training seconds at the checkpoints along each run: a thin line per run
    (scene), a thick one per method through the mean over scenes of each checkpoint."""
    plt = _pyplot()
    if plt is None or not rows:
        return None
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for color, (label, group) in zip(COLORS * 4, group_rows(rows, lambda r: r["variant"]).items()):
        curves = [r.get("curve") or [] for r in group]
        for curve in curves:
            for ax, metric in zip(axes, ("cd", "psnr")):
                ax.plot([p["train_seconds"] for p in curve], [_nan(p.get(metric)) for p in curve],
                        color=color, alpha=0.3, linewidth=0.8, marker=".")
        length = min((len(c) for c in curves), default=0)
        if length:
            for ax, metric in zip(axes, ("cd", "psnr")):
                xs = [mean_sd(c[i]["train_seconds"] for c in curves)[0] for i in range(length)]
                ys = [mean_sd(c[i].get(metric) for c in curves)[0] for i in range(length)]
                ax.plot(xs, ys, color=color, linewidth=2.2, marker="o", label=f"{label} (mean of {len(curves)})")
    axes[0].set(xlabel="training seconds", ylabel="Chamfer distance (lower is better)", title="CD")
    axes[1].set(xlabel="training seconds", ylabel="PSNR dB, held-out views (higher is better)", title="PSNR")
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=8)
    return _save(plt, fig, path, title)


def plot_against(rows: Sequence[dict[str, Any]], x_key: str, metrics: Sequence[str], path: Path, title: str,
                 xlabel: str, fits: bool = False) -> Path | None:
    """``metrics`` against ``x_key``: per method the mean over scenes at each x (error bars: sd), or,
    with ``fits``, every row as a point plus its method's least-squares line."""
    plt = _pyplot()
    if plt is None or not rows:
        return None
    fig, axes = plt.subplots(1, len(metrics), figsize=(5.5 * len(metrics), 4.2), squeeze=False)
    for color, (label, group) in zip(COLORS * 4, group_rows(rows, lambda r: r["variant"]).items()):
        for ax, metric in zip(axes[0], metrics):
            if fits:
                xs, ys = [r[x_key] for r in group], [_nan(r.get(metric)) for r in group]
                ax.scatter(xs, ys, color=color, s=18, label=label)
                line = linear_fit(xs, ys)
                if line is not None:
                    lo, hi = min(finite(xs)), max(finite(xs))
                    ax.plot([lo, hi], [line[1] + line[0] * lo, line[1] + line[0] * hi], color=color, linewidth=1.5)
            else:
                by_x = group_rows(sorted(group, key=lambda r: r[x_key]), lambda r: r[x_key])
                stats = [mean_sd(r.get(metric) for r in g) for g in by_x.values()]
                ax.errorbar(list(by_x), [s[0] for s in stats], yerr=[s[1] for s in stats], color=color,
                            marker="o", capsize=3, label=label)
    for ax, metric in zip(axes[0], metrics):
        ax.set(xlabel=xlabel, ylabel=METRIC_TITLES.get(metric, metric), title=METRIC_TITLES.get(metric, metric))
        ax.grid(alpha=0.3)
    axes[0][-1].legend(fontsize=8)
    return _save(plt, fig, path, title)


def plot_stacked_bars(parts: dict[str, dict[str, float]], path: Path, title: str, xlabel: str) -> Path | None:
    """A horizontal bar per label (``parts``: label -> {part: value}), split into its parts, which have the
    same color in every bar (the parts of the first label set the order)."""
    plt = _pyplot()
    if plt is None or not parts:
        return None
    names = list(dict.fromkeys(name for values in parts.values() for name in values))
    labels = list(parts)
    fig, ax = plt.subplots(figsize=(10, 1.2 + 0.55 * len(labels)))
    left = [0.0] * len(labels)
    palette, extra = plt.get_cmap("tab10"), plt.get_cmap("Dark2")
    for index, name in enumerate(names):
        color = palette(index) if index < 10 else extra(index % 8)
        widths = [max(0.0, _nan(parts[label].get(name, 0.0))) for label in labels]
        ax.barh(labels, widths, left=left, color=color, label=name)
        left = [a + b for a, b in zip(left, widths)]
    ax.invert_yaxis()
    ax.set(xlabel=xlabel, title=title)
    ax.grid(axis="x", alpha=0.3)
    ax.legend(fontsize=8, ncol=min(len(names), 5), loc="upper center", bbox_to_anchor=(0.5, -0.25 - 0.1 / len(labels)))
    return _save(plt, fig, path, bbox_inches="tight")


def _save(plt, fig, path: Path, title: str | None = None, **savefig: Any) -> Path:
    """Finish a figure: its title, tight layout, written to ``path`` at 110 dpi, closed."""
    if title is not None:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110, **savefig)
    plt.close(fig)
    return path


def _nan(value: Any) -> float:
    return float("nan") if value is None else float(value)


def linear_fit(xs: Sequence[Any], ys: Sequence[Any]) -> tuple[float, float, float] | None:
    """Least-squares line through the finite (x, y) pairs: (slope, intercept, Pearson r); None when
    fewer than two distinct x values."""
    points = [(float(x), float(y)) for x, y in zip(xs, ys) if len(finite([x, y])) == 2]
    if len({x for x, _ in points}) < 2:
        return None
    n = len(points)
    mx, my = sum(x for x, _ in points) / n, sum(y for _, y in points) / n
    sxx = sum((x - mx) ** 2 for x, _ in points)
    syy = sum((y - my) ** 2 for _, y in points)
    sxy = sum((x - mx) * (y - my) for x, y in points)
    slope = sxy / sxx
    r = sxy / math.sqrt(sxx * syy) if syy > 0 else float("nan")
    return slope, my - slope * mx, r
