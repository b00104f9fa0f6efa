"""How well a trained field explains each training view, plain and low-passed: can any per-view residual
statistic tell consistent inputs from inconsistent ones?

    python benchmarks/bench_residual_spread.py RUN [RUN ...] [--side 64] [--sigmas 0,1,2]

For each run folder, renders every training view (canonical path) at ``--side`` px, compares it with the
input (area-averaged to the same size) over the foreground, after blurring both with a Gaussian of each
sigma (px at that size; 0: no blur), and prints the per-view PSNR and its spread (max - min).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
import torch.nn.functional as F

from va_plugin.cli.run import load_run
from va_plugin.model_components.losses import psnr_from_mse
from va_plugin.rays import RayBundle


def blur(image: torch.Tensor, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur of ``[1, C, H, W]`` with replicated borders."""
    if sigma <= 0:
        return image
    k = int(3 * sigma) * 2 + 1
    x = torch.arange(k, dtype=image.dtype) - k // 2
    w = torch.exp(-x ** 2 / (2 * sigma * sigma))
    w = w / w.sum()
    c = image.shape[1]
    image = F.conv2d(F.pad(image, (k // 2, k // 2, 0, 0), mode="replicate"), w.view(1, 1, 1, k).expand(c, 1, 1, k),
                     groups=c)
    return F.conv2d(F.pad(image, (0, 0, k // 2, k // 2), mode="replicate"), w.view(1, 1, k, 1).expand(c, 1, k, 1),
                    groups=c)


@torch.no_grad()
def residuals(pipeline, side: int, sigmas) -> dict:
    dm = pipeline.datamanager
    if dm.masks is None:
        raise SystemExit("error: the run's inputs have no masks; the statistic is over the foreground")
    height, width = dm.images.shape[1:3]
    stride = max(1, height // side)
    rows, cols = torch.meshgrid(torch.arange(stride // 2, height, stride), torch.arange(stride // 2, width, stride),
                                indexing="ij")
    shape = rows.shape
    rows, cols = rows.reshape(-1), cols.reshape(-1)
    out = {s: [] for s in sigmas}
    for view in range(dm.num_train_views):
        views = torch.full_like(rows, view)
        origins, directions = dm.cameras.generate_rays(views, rows, cols)
        rgb = pipeline.model.render_rays(RayBundle(origins, directions, torch.full_like(views, -1)), keys=("rgb",))["rgb"]
        render = rgb.reshape(*shape, 3).permute(2, 0, 1)[None]
        target = F.adaptive_avg_pool2d(dm.images[view, ..., :3].permute(2, 0, 1)[None], shape)
        mask = F.adaptive_avg_pool2d(dm.masks[view].permute(2, 0, 1)[None, :1].float(), shape) > 0.5
        for sigma in sigmas:
            error = ((blur(render, sigma) - blur(target, sigma)) ** 2).mean(1, keepdim=True)[mask]
            out[sigma].append(float(psnr_from_mse(error.mean())))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--side", type=int, default=64)
    parser.add_argument("--sigmas", default="0,1,2")
    args = parser.parse_args(argv)
    sigmas = [float(s) for s in args.sigmas.split(",")]
    for run in args.runs:
        if not run.is_dir():
            raise SystemExit(f"error: no run folder at {run}")
        pipeline, _ = load_run(run)
        pipeline.model.eval()
        for sigma, values in residuals(pipeline, args.side, sigmas).items():
            print(f"{run} blur {sigma:g} px: " + ", ".join(f"{v:.2f}" for v in values)
                  + f" dB (spread {max(values) - min(values):.2f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
