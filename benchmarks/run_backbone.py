"""Backbones on the Google Scanned Objects: accuracy, time, and what more compute does.

Every variant (a registered method, optionally with one of its presets) trains on every scene at every
inconsistency level and every budget (a multiple of the variant's default step budget), with the same
seed, and is scored the same way: the mesh against the object's ground truth (CD, IoU, F-score), every
held-out view against its ground-truth render (PSNR, SSIM, LPIPS). Writes into OUT:

    backbone.md       per level and budget: mean ± sd over objects, then per-object rows
    backbone.csv/json one row per (scene, level, variant, budget); the JSON holds each run's time curve
    backbone_time.png CD and PSNR against training seconds, from checkpoints along each run
    rows.jsonl        finished rows (what --resume reads); scenes/ (the scene cache) and runs/ (run folders)

    python benchmarks/run_backbone.py --preset gso10 [--variants neus,neus:mlp,ngp] [--levels 0,2]
        [--budgets 1,2,4] [--scenes gso:alarm,gso:lion] [--out DIR] [--resume] [--jobs 2]

``--variants`` takes METHOD or METHOD:PRESET (``neus:mlp`` is the positional-encoding NeuS that was the
default before the hash-grid field). ``--budgets 1,2,4`` checks that more compute never hurts.
"""

from __future__ import annotations

import itertools
import sys
from pathlib import Path
from typing import Any

from va_plugin.bench.experiment import Experiment, axis_values, comma_list
from va_plugin.bench.presets import BACKBONES
from va_plugin.bench.report import (
    fmt,
    group_rows,
    markdown_table,
    plot_time_curves,
    report_sections,
    summary_table,
    write_outputs,
)
from va_plugin.bench.rows import RowSpec, scene_of
from va_plugin.bench.scenes.inconsistency import parse_kinds
from va_plugin.cli.bench import main as bench_main
from va_plugin.errors import ConfigError
from va_plugin.registry import get_method

METHOD_OF = {method: (backbone, adaptive) for backbone, pair in BACKBONES.items()
             for adaptive, method in enumerate(pair)}
"""Registered method -> (backbone, view-adaptive?)."""


def add_arguments(parser) -> None:
    parser.add_argument("--variants", default="neus,neus:mlp",
                        help="comma-separated METHOD[:PRESET][@KEY=VALUE...] (default neus,neus:mlp: the "
                             "hash-grid NeuS against the positional-encoding NeuS that was the default before "
                             "it); each @KEY=VALUE is a --set override of that variant alone")
    parser.add_argument("--levels", default=None, help="comma-separated inconsistency levels (default 0,2)")
    parser.add_argument("--kinds", default=None,
                        help="semicolon-separated sets of inconsistency kinds, each a comma-separated subset of "
                             "geometric,appearance,pose (default: all three together); e.g. "
                             "'appearance;geometric,pose' splits a level's error into its color and its "
                             "geometric part. Scenes with fewer kinds are named NAME+kind+kind")
    parser.add_argument("--budgets", default="1",
                        help="comma-separated multiples of each variant's default step budget (e.g. 1,2,4)")


def parse_variants(text: str) -> list[tuple[str, str, tuple[str, ...]]]:
    """``METHOD[:PRESET][@KEY=VALUE...],...`` -> [(method, preset or "", overrides)], checked against the
    registry; each ``@KEY=VALUE`` is a ``--set`` override of that variant only."""
    variants = []
    for item in comma_list(text):
        head, *overrides = item.split("@")
        for override in overrides:
            if "=" not in override:
                raise ConfigError(f"--variants: {item!r}: an override after '@' reads KEY=VALUE, got {override!r}")
        method, _, preset = head.partition(":")
        if method not in METHOD_OF:
            raise ConfigError(f"--variants: unknown method {method!r}; known: {', '.join(METHOD_OF)}")
        spec = get_method(method)
        if preset and preset not in spec.presets:
            raise ConfigError(f"--variants: {method} has no preset {preset!r}; it has {', '.join(spec.presets)}")
        variants.append((method, preset, tuple(overrides)))
    if not variants:
        raise ConfigError("--variants is empty")
    return variants


def parse_kind_sets(text: str | None) -> list[tuple[str, ...] | None]:
    """``--kinds``: ``None`` (every kind together) or one tuple of kinds per ``;``-separated set."""
    if text is None or not text.strip():
        return [None]
    sets = [parse_kinds(part) for part in text.split(";") if part.strip()]
    if not sets:
        raise ConfigError(f"--kinds names no set of kinds: {text!r}")
    return sets


def plan(preset, args, sources: list[str]) -> list[RowSpec]:
    variants = parse_variants(args.variants)
    budgets = [float(b) for b in comma_list(args.budgets, float)]
    if not budgets or min(budgets) <= 0:
        raise ConfigError(f"--budgets takes positive multiples, got {args.budgets!r}")
    kind_sets = parse_kind_sets(args.kinds)
    rows = []
    for level, kinds, source in itertools.product(axis_values(args.levels, (0, 2)), kind_sets, sources):
        scene = scene_of(source, preset, args.seed, level=level, kinds=kinds)
        for method, method_preset, overrides in variants:
            backbone, adaptive = METHOD_OF[method]
            default_steps = preset.steps.get(backbone) or get_method(method).make_config(
                method_preset or None).max_steps
            for budget in budgets:
                label = method + (f":{method_preset}" if method_preset else "") + \
                    "".join(f"@{o}" for o in overrides) + ("" if budget == 1 else f" x{budget:g}")
                rows.append(RowSpec("backbone", scene, backbone, bool(adaptive), variant=label,
                                    overrides=overrides, method_preset=method_preset or None,
                                    steps=max(1, round(default_steps * budget))))
    return rows


def _budget_check(rows: list[dict[str, Any]]) -> str:
    """Per variant and level, the change of held-out PSNR and CD from budget x1 to each larger budget,
    paired by object (the issue's test: no lower PSNR than -0.2 dB, no higher CD than +3%)."""
    base = {(r["scene"], r["level"], r["variant"]): r for r in rows if " x" not in r["variant"]}
    body = []
    for label, group in group_rows([r for r in rows if " x" in r["variant"]],
                                   lambda r: (r["variant"], r["level"])).items():
        pairs = [(base[(r["scene"], r["level"], r["variant"].split(" x")[0])], r) for r in group
                 if (r["scene"], r["level"], r["variant"].split(" x")[0]) in base]
        if not pairs:
            continue
        d_psnr = [b["psnr"] - a["psnr"] for a, b in pairs]
        d_cd = [(b["cd"] - a["cd"]) / a["cd"] * 100 for a, b in pairs if a["cd"] == a["cd"] and a["cd"] > 0]
        body.append([label[0], label[1], len(pairs), f"{sum(d_psnr) / len(d_psnr):+.2f}", f"{min(d_psnr):+.2f}",
                     f"{sum(d_cd) / max(1, len(d_cd)):+.1f}%" if d_cd else "-",
                     f"{max(d_cd):+.1f}%" if d_cd else "-"])
    if not body:
        return ""
    return "## More compute: change from budget x1, paired by object\n\n" + markdown_table(
        ["variant", "level", "objects", "PSNR mean", "PSNR worst", "CD mean", "CD worst"], body)


def report(rows: list[dict[str, Any]], out: Path, meta: dict[str, Any]) -> list[Path]:
    body = []
    for level, group in group_rows(rows, lambda r: r["level"]).items():
        scenes = len({r["scene"] for r in group})
        seconds = markdown_table(["variant", "median train s", "steps"], [
            [label, fmt(sorted(r["train_seconds"] for r in g)[len(g) // 2], "train_seconds"), g[0]["steps"]]
            for label, g in group_rows(group, lambda r: r["variant"]).items()])
        body += [f"## Level {level}: mean ± sd over {scenes} object(s)", summary_table(group, expected=scenes),
                 seconds]
    budget = _budget_check(rows)
    if budget:
        body.append(budget)
    return write_outputs(rows, out, "backbone", meta,
                         report_sections("Backbones on the Google Scanned Objects", meta, rows, body,
                                         ("backbone_time.png", "CD and PSNR against training seconds")),
                         {"backbone_time.png": lambda path: plot_time_curves(
                             rows, path, "Error against training time (checkpoints along each run)")})


EXPERIMENT = Experiment("backbone", "Backbones", __doc__, plan, report, add_arguments=add_arguments,
                        fixed=("level",))


def main(argv=None) -> int:
    return bench_main(EXPERIMENT, argv)


if __name__ == "__main__":
    sys.exit(main())
