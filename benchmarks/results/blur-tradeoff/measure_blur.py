"""Held-out PSNR / LPIPS of a run's renders after a Gaussian blur of each sigma (in pixels; 0 = as rendered).

Asks whether a longer run loses PSNR because its renders are sharper in slightly wrong places (then some
blur gives the PSNR back, and more of it than the same blur gives the shorter run) or because their content
is worse (then no blur does). Each view is rendered once; the blur is applied to the render only.
Usage: python measure_blur.py RUN[,RUN...] 0,0.5,1,1.5 OUT.jsonl
"""
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

from va_plugin.cli.run import load_run
from va_plugin.eval.image import psnr
from va_plugin.eval.lpips import lpips
from va_plugin.export.render import held_out_views

torch.set_num_threads(1)
sigmas = [float(x) for x in sys.argv[2].split(",")]
with open(sys.argv[3], "a") as out:
    for run in sys.argv[1].split(","):
        pipeline, state = load_run(Path(run), device="cpu")
        scores = {s: {"psnr": [], "lpips": []} for s in sigmas}
        for _, render, target in held_out_views(pipeline, progress=False):
            for s in sigmas:
                img = render if s == 0 else cv2.GaussianBlur(render, (0, 0), sigmaX=s, sigmaY=s,
                                                               borderType=cv2.BORDER_REPLICATE)
                scores[s]["psnr"].append(psnr(img, target))
                scores[s]["lpips"].append(lpips(img, target))
        for s in sigmas:
            rec = dict(run=run, scene=Path(run).parts[-3], variant=Path(run).name, steps=int(state["step"]),
                       sigma=s, psnr=float(np.mean(scores[s]["psnr"])), lpips=float(np.mean(scores[s]["lpips"])),
                       views=len(scores[s]["psnr"]))
            print(json.dumps(rec), flush=True)
            out.write(json.dumps(rec) + "\n")
            out.flush()
