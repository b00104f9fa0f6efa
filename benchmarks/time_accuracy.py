"""Accuracy against wall time per object: one point per arm, the figure that speed changes are judged by.

An arm is a name, the variants of ``run_all_views.py`` rows that hold its accuracy (one or more runs per
object, e.g. two ray seeds), and its wall seconds per object measured on idle cores (``va-train ...
--export-mesh`` timed alone: the rows' own seconds come from runs that share the machine). The figure shows
the mean PSNR, LPIPS and CD over the objects every arm has, each run's mean as a small marker and the arm's
mean as a large one; the table goes to stdout.

    python benchmarks/time_accuracy.py --rows benchmarks/results/all-views/rows-l2.jsonl --views 16 \\
        --arm "41b20a6=,seed43@390.3" --arm "kernels=kernel,kernel-seed43@184.3" --out FIGURE.png

In ``--arm NAME=VARIANTS@SECONDS`` the variants are comma-separated; an empty name is the default's rows.
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

METRICS = (("psnr", "held-out PSNR (dB), higher is better"), ("lpips", "LPIPS, lower is better"),
           ("cd", "Chamfer distance, lower is better"))


def parse_arm(text: str) -> tuple[str, list[str], float]:
    """``NAME=VARIANTS@SECONDS`` -> (name, variants, seconds)."""
    try:
        name, rest = text.split("=", 1)
        variants, seconds = rest.rsplit("@", 1)
        return name, variants.split(","), float(seconds)
    except ValueError:
        raise SystemExit(f"error: --arm takes NAME=VARIANT[,VARIANT...]@SECONDS, got {text!r}") from None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=Path, required=True)
    parser.add_argument("--views", type=int, default=16)
    parser.add_argument("--arm", action="append", required=True, help="NAME=VARIANT[,VARIANT...]@SECONDS")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    arms = [parse_arm(a) for a in args.arm]
    rows = [json.loads(line) for line in args.rows.read_text().splitlines() if line.strip()]
    by: dict[tuple[str, str], dict] = {(r["object"], r.get("variant", "")): r for r in rows if r["views"] == args.views}
    objects = sorted(o for o in {o for o, _ in by} if all((o, v) in by for _, vs, _ in arms for v in vs))
    if not objects:
        raise SystemExit("error: no object has rows for every variant of every arm")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    print("| arm | wall s per object | " + " | ".join(m for m, _ in METRICS) + " | runs |")
    print("|---|---|" + "---|" * len(METRICS) + "---|")
    for index, (name, variants, seconds) in enumerate(arms):
        color = f"C{index}"
        run_means = {m: [statistics.mean(by[(o, v)][m] for o in objects) for v in variants] for m, _ in METRICS}
        for ax, (metric, label) in zip(axes, METRICS):
            ax.scatter([seconds] * len(variants), run_means[metric], s=12, color=color, alpha=0.5)
            ax.scatter([seconds], [statistics.mean(run_means[metric])], s=60, color=color, label=name)
            ax.set_xlabel("wall seconds per object, 2 idle cores, with the mesh")
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
        print(f"| {name} | {seconds:g} | " + " | ".join(f"{statistics.mean(run_means[m]):.4g}" for m, _ in METRICS)
              + f" | {len(variants)} |")
    axes[0].legend(fontsize=8)
    fig.suptitle(f"Means over {len(objects)} objects, {args.views} views (small markers: single runs)")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"figure: {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
