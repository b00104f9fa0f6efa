"""Held-out views of several runs side by side: per row (one view) the ground truth, then for each run its
render and its error map (mean absolute RGB error x4, clipped). Behind gso_bell_l0_neus_1x_2x.png.
Usage: python pair_figure.py RUN[,RUN...] VIEW[,VIEW...] OUT.png
"""
import sys, numpy as np, torch, cv2
from pathlib import Path
from va_plugin.cli.run import load_run
from va_plugin.export.render import render_view
torch.set_num_threads(1)
runs = sys.argv[1].split(","); views = [int(v) for v in sys.argv[2].split(",")]; out = sys.argv[3]
rows = []
for v in views:
    cols = []; gt = None
    for run in runs:
        p, s = load_run(Path(run), device="cpu")
        img = render_view(p.model, p.datamanager.test.cameras, v)
        gt = p.datamanager.test.images[v].numpy()
        err = np.clip(np.abs(img - gt).mean(-1, keepdims=True) * 4, 0, 1).repeat(3, -1)
        cols += [img, err]
    rows.append(np.concatenate([gt] + cols, axis=1))
im = (np.concatenate(rows, axis=0) * 255).round().astype(np.uint8)
cv2.imwrite(out, cv2.cvtColor(im, cv2.COLOR_RGB2BGR)); print(out, im.shape)
