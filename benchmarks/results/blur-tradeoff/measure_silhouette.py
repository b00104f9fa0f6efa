"""Signed silhouette error of a run's held-out views: how much the rendered opacity spills outside the
ground-truth mask (too fat) and how much of the mask it leaves empty (too thin), each as a share of the
mask's area, plus the same on the training views (what the fit itself leaves).
Usage: python measure_silhouette.py RUN[,RUN...] OUT.jsonl
"""
import json
import sys
from pathlib import Path

import numpy as np
import torch

from va_plugin.cli.run import load_run
from va_plugin.export.render import render_view

torch.set_num_threads(1)


def split(model, dataset):
    extra, missing = [], []
    for i in range(len(dataset)):
        acc = render_view(model, dataset.cameras, i, keys=("accumulation",))[0][..., 0]
        m = dataset.masks[i].numpy().reshape(acc.shape)
        area = max(m.sum(), 1.0)
        extra.append(float(np.clip(acc - m, 0, None).sum() / area))
        missing.append(float(np.clip(m - acc, 0, None).sum() / area))
    return float(np.mean(extra)), float(np.mean(missing))


with open(sys.argv[2], "a") as out, torch.no_grad():
    for run in sys.argv[1].split(","):
        pipeline, state = load_run(Path(run), device="cpu")
        dm = pipeline.datamanager
        te, tm = split(pipeline.model, dm.test)
        re_, rm = split(pipeline.model, dm.train)
        rec = dict(run=run, scene=Path(run).parts[-3], steps=int(state["step"]), held_out_extra=te,
                   held_out_missing=tm, train_extra=re_, train_missing=rm)
        print(json.dumps(rec), flush=True)
        out.write(json.dumps(rec) + "\n")
