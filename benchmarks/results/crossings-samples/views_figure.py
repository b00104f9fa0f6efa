"""Held-out views of several runs of one object side by side, with each run's error against the truth.

Usage: python views_figure.py OUT.png N LABEL=RENDERS_DIR [LABEL=RENDERS_DIR ...]

Each RENDERS_DIR holds `va-export render`'s ``view_XXX.png`` (render | ground truth). The N views where
the first and the last run differ most in PSNR are shown: one row per view, the runs' renders, the truth,
then |render - truth| x3 per run, each tile titled with its PSNR.
"""
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from va_plugin.data.images import read_image  # noqa: E402
from va_plugin.eval.image import psnr  # noqa: E402

USAGE = "usage: python views_figure.py OUT.png N LABEL=RENDERS_DIR [LABEL=RENDERS_DIR ...]"
if len(sys.argv) < 4 or not sys.argv[2].isdigit() or int(sys.argv[2]) < 1 \
        or any("=" not in arg for arg in sys.argv[3:]):
    sys.exit(USAGE)
out, n = Path(sys.argv[1]), int(sys.argv[2])
runs = [arg.split("=", 1) for arg in sys.argv[3:]]
names = sorted(p.name for p in Path(runs[0][1]).glob("view_*.png"))
for label, folder in runs:
    if not names or sorted(p.name for p in Path(folder).glob("view_*.png")) != names:
        sys.exit(f"{label}: {folder} must hold the same view_XXX.png files (va-export render) as the first run's "
                 f"folder, and at least one")
pairs = {label: [read_image(Path(d) / name)[..., :3] for name in names] for label, d in runs}
width = pairs[runs[0][0]][0].shape[1] // 2
renders = {label: [p[:, :width] for p in ps] for label, ps in pairs.items()}
truth = [p[:, width:] for p in pairs[runs[0][0]]]
first, last = runs[0][0], runs[-1][0]
gap = [abs(psnr(renders[first][i], truth[i]) - psnr(renders[last][i], truth[i])) for i in range(len(names))]
chosen = list(np.argsort(gap)[::-1][:n])
cols = 2 * len(runs) + 1
fig, axes = plt.subplots(len(chosen), cols, figsize=(2.2 * cols, 2.3 * len(chosen)), squeeze=False)
for row, i in enumerate(chosen):
    tiles = [(f"{label} {psnr(renders[label][i], truth[i]):.2f} dB", renders[label][i]) for label, _ in runs]
    tiles.append((f"truth ({names[i][:-4]})", truth[i]))
    tiles += [(f"|{label} - truth| x3", np.clip(3 * np.abs(renders[label][i] - truth[i]), 0, 1)) for label, _ in runs]
    for ax, (title, image) in zip(axes[row], tiles):
        ax.imshow(image)
        ax.set_title(title, fontsize=7)
        ax.axis("off")
fig.tight_layout()
fig.savefig(out, dpi=110)
print(f"wrote {out}: views {[names[i] for i in chosen]}")
