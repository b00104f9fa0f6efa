"""Held-out outlines of runs against the ground-truth masks: grey where both agree, red where a run renders
opacity outside the mask (too fat), blue where it leaves the mask empty (too thin). One row per group of
runs (comma-separated), one tile per run, then the same held-out view for the next group.
Usage: python outline_figure.py OUT.png VIEW RUN,RUN[,...] [RUN,RUN ...]
"""
import sys
from pathlib import Path

import numpy as np
import torch

from va_plugin.cli.run import load_run
from va_plugin.data.images import write_image
from va_plugin.export.render import render_view

torch.set_num_threads(1)
out, view = Path(sys.argv[1]), int(sys.argv[2])
rows = []
with torch.no_grad():
    for group in sys.argv[3:]:
        tiles = []
        for run in group.split(","):
            pipeline, _ = load_run(Path(run), device="cpu")
            test = pipeline.datamanager.test
            acc = render_view(pipeline.model, test.cameras, view, keys=("accumulation",))[0][..., 0]
            mask = test.masks[view].numpy().reshape(acc.shape)
            both = np.minimum(acc, mask)
            fat = np.clip(acc - mask, 0, 1)
            thin = np.clip(mask - acc, 0, 1)
            tile = np.ones(acc.shape + (3,), np.float32)
            tile -= both[..., None] * 0.4
            tile -= fat[..., None] * np.array([0.0, 0.9, 0.9], np.float32)
            tile -= thin[..., None] * np.array([0.9, 0.9, 0.0], np.float32)
            tiles.append(np.clip(tile, 0, 1))
            print(run, f"too fat {fat.sum() / mask.sum():.3f}, too thin {thin.sum() / mask.sum():.3f}", flush=True)
        rows.append(np.concatenate(tiles, axis=1))
write_image(out, np.concatenate(rows, axis=0))
