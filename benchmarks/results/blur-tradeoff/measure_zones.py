"""Where a run's held-out squared error lies: inside the object, on its silhouette's edge, or outside it.

Each held-out view's per-pixel squared error (mean over RGB) is split by the ground-truth mask into an edge
band (pixels within BAND px of the silhouette's boundary, inside or out), the interior (mask, off the band)
and the outside (no mask, off the band). Each zone's figure is its share of the view's MSE (sum of its
pixels' errors over all the view's pixels), so the three add up to the MSE; the means over views go out.
Usage: python measure_zones.py RUN[,RUN...] OUT.jsonl [BAND]
"""
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

from va_plugin.cli.run import load_run
from va_plugin.export.render import held_out_views

torch.set_num_threads(1)
band = int(sys.argv[3]) if len(sys.argv) > 3 else 3
kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * band + 1, 2 * band + 1))
with open(sys.argv[2], "a") as out:
    for run in sys.argv[1].split(","):
        pipeline, state = load_run(Path(run), device="cpu")
        masks = pipeline.datamanager.test.masks
        if masks is None:
            raise SystemExit(f"{run}: the held-out views have no masks")
        zones = {"interior": [], "edge": [], "outside": [], "mse": []}
        for i, render, target in held_out_views(pipeline, progress=False):
            m = (masks[i].numpy().reshape(render.shape[:2]) > 0.5).astype(np.uint8)
            edge = (cv2.dilate(m, kernel) - cv2.erode(m, kernel)) > 0
            err = ((render - target) ** 2).mean(axis=-1)
            n = err.size
            zones["edge"].append(err[edge].sum() / n)
            zones["interior"].append(err[(m > 0) & ~edge].sum() / n)
            zones["outside"].append(err[(m == 0) & ~edge].sum() / n)
            zones["mse"].append(err.mean())
        rec = dict(run=run, scene=Path(run).parts[-3], variant=Path(run).name, steps=int(state["step"]), band=band,
                   **{k: float(np.mean(v)) for k, v in zones.items()},
                   psnr_of_mean_mse=float(-10 * np.log10(max(np.mean(zones["mse"]), 1e-10))))
        print(json.dumps(rec), flush=True)
        out.write(json.dumps(rec) + "\n")
        out.flush()
