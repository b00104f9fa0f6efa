"""The inv_s floor's trade between held-out PSNR and LPIPS: GSO-10 means at level 2, one point per run of the
default with a given floor, against issue 19's targets (PSNR >= the old `neus` + 2 dB, LPIPS <= 0.15).

Usage: python tradeoff.py OUT.png OLD.csv LABEL=ROWS.jsonl [LABEL=ROWS.jsonl ...]

OLD.csv is run_backbone's table of the old `neus` (benchmarks/results/gso10-l2-mlp/backbone.csv), whose mean
PSNR is the base of the +2 dB. Each ROWS file holds run_backbone rows of the same objects as OLD.csv; a file
with other objects is refused.
"""
import csv
import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

USAGE = "usage: python tradeoff.py OUT.png OLD.csv LABEL=ROWS.jsonl [LABEL=ROWS.jsonl ...]"

if len(sys.argv) < 4 or any("=" not in arg for arg in sys.argv[3:]) or not Path(sys.argv[2]).is_file():
    sys.exit(USAGE)
with open(sys.argv[2]) as f:
    old = list(csv.DictReader(f))
scenes = sorted(r["scene"] for r in old)
OLD_NEUS_PSNR = float(np.mean([float(r["psnr"]) for r in old]))
points = []
for arg in sys.argv[3:]:
    label, path = arg.split("=", 1)
    if not Path(path).is_file():
        sys.exit(f"{label}: {path} is not a file")
    rows = [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]
    these = sorted(r["scene"] for r in rows)
    if these != scenes or len(set(these)) != len(these):
        sys.exit(f"{label}: {path} holds {these}, not the objects of {sys.argv[2]} ({scenes}), once each")
    points.append((label, np.mean([r["psnr"] for r in rows]), np.mean([r["lpips"] for r in rows])))

fig, ax = plt.subplots(figsize=(5.5, 4.2))
for label, p, l in points:
    ax.plot(l, p - OLD_NEUS_PSNR, "o", color="C0")
    ax.annotate(f"{label}\n{p - OLD_NEUS_PSNR:+.2f} dB, {l:.3f}", (l, p - OLD_NEUS_PSNR), textcoords="offset points",
                xytext=(6, -4), fontsize=8)
ax.axhline(2.0, color="C3", lw=1, ls="--", label="target: +2 dB")
ax.axvline(0.15, color="C2", lw=1, ls="--", label="target: LPIPS <= 0.15")
ax.set_xlabel(f"held-out LPIPS (mean of {len(scenes)} objects)")
ax.set_ylabel(f"held-out PSNR over the old neus ({OLD_NEUS_PSNR:.2f} dB)")
ax.set_title("inv_s floor: PSNR against LPIPS, GSO level 2", fontsize=10)
ax.legend(fontsize=8, loc="lower right")
lo, hi = min(l for _, _, l in points), max(l for _, _, l in points)
ax.set_xlim(min(lo, 0.15) - 0.01, max(hi, 0.15) + 0.02)
fig.tight_layout()
fig.savefig(sys.argv[1], dpi=120)
print(f"wrote {sys.argv[1]}")
