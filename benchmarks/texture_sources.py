"""Where each texel's color comes from, with the bake as it was and as it is (issue 67, white patches).

For each run folder: extract the mesh (as ``va-recon`` does), bake it twice on one UV atlas, and report per
bake the share of the surface's texels that

- no view sees (``unseen``: filled by the fall-back),
- take color from a view whose bilinear footprint touches a pixel outside that view's mask
  (``outside``: mask < 0.5) or only partly inside it (``partial``: mask < 0.99),
- are near-white (every channel at least 0.95; ``white``), and, of the unseen ones, near-white too.

With ``--score`` the textured meshes are also rendered at the run's held-out views (GSO scenes) and scored
like the field (PSNR, LPIPS). The two bakes:

- ``before``: pixels whose mask is above 0.5 give color, unseen texels take the field's own color;
- ``after`` (the default now): only pixels whose mask is at least 0.99 give color, unseen texels take the
  color of the nearest seen surface.

    OMP_NUM_THREADS=1 python benchmarks/texture_sources.py --runs RUN [RUN ...] --out ROWS.jsonl [--score]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from va_plugin.api import load_run
from va_plugin.bench.store import append_row, keyed_rows
from va_plugin.cli.common import friendly_errors
from va_plugin.export.atlas import rasterize_uv
from va_plugin.export.mesh import extract_mesh
from va_plugin.export.texture import bake_texture, run_views
from va_plugin.export.views import OPAQUE, rays_through

WHITE = 0.95


def field_color(model):
    """The model's canonical surface color at points with normals: the fall-back of the bake before."""

    def color(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        model.eval()
        with torch.no_grad():
            out = [model.surface_color(torch.as_tensor(points[i:i + 16384]),
                                       torch.as_tensor(normals[i:i + 16384], dtype=torch.float32))
                   for i in range(0, len(points), 16384)]
        return torch.cat(out).numpy() if out else np.zeros((0, 3), np.float32)

    return color


def footprint_mask(mask: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The lowest soft-mask value among the 2x2 pixels a bilinear lookup at ``x, y`` reads."""
    h, w = mask.shape
    x0 = np.clip(np.floor(np.clip(x, 0, w - 1)).astype(np.int64), 0, max(w - 2, 0))
    y0 = np.clip(np.floor(np.clip(y, 0, h - 1)).astype(np.int64), 0, max(h - 2, 0))
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    return np.minimum.reduce([mask[y0, x0], mask[y0, x1], mask[y1, x0], mask[y1, x1]])


def sources(textured, report, cameras, soft_masks) -> dict:
    """Shares of the surface's texels by where their color came from, and the near-white share."""
    size = textured.image.shape[0]
    face, bary = rasterize_uv(textured.uv, textured.faces, size)
    covered = face >= 0
    corners = textured.faces[face[covered]]
    points = np.einsum("mk,mkc->mc", bary[covered], textured.vertices[corners]).astype(np.float32)
    share = report.weight_maps[:, covered]  # [n, m]
    seen = share.sum(0) > 0
    lowest = np.ones(len(points), np.float32)
    if soft_masks is not None:
        for k in range(len(share)):
            idx = np.nonzero(share[k] > 0)[0]
            if len(idx):
                _, _, _, pix = rays_through(cameras, k, points[idx])
                lowest[idx] = np.minimum(lowest[idx], footprint_mask(soft_masks[k], pix[:, 0], pix[:, 1]))
    white = (textured.image[covered] >= WHITE).all(-1)
    m = max(len(points), 1)
    return {"texels": len(points), "unseen": float((~seen).sum() / m),
            "outside": float((seen & (lowest < 0.5)).sum() / m),
            "partial": float((seen & (lowest < OPAQUE)).sum() / m),
            "white": float(white.sum() / m),
            "white_unseen": float((white & ~seen).sum() / m),
            "white_seen": float((white & seen).sum() / m)}


def evaluate(run: Path, size: int, score: bool) -> dict:
    pipeline, state = load_run(run, device="cpu").parts()
    dm = pipeline.datamanager
    soft = None if dm.masks is None else dm.masks.cpu().numpy().reshape(dm.images.shape[:3]).astype(np.float32)
    mesh = extract_mesh(pipeline.model, resolution=128, with_color=False)
    record = {"run": str(run), "steps": int(state["step"]), "faces": len(mesh.faces)}
    atlas = None
    for name, opaque, fallback in (("before", 0.5, field_color(pipeline.model)), ("after", OPAQUE, None)):
        views = run_views(pipeline, opaque=opaque)
        textured, report = bake_texture(mesh, views, size=size, fallback=fallback, atlas=atlas)
        atlas = (textured.vertices, textured.faces, textured.uv)
        record[name] = sources(textured, report, views.cameras, soft)
        if score:
            from va_plugin.eval.mesh_render import textured_mesh_metrics

            scores = textured_mesh_metrics(pipeline, textured, progress=False)
            record[name].update({k: scores[k] for k in ("psnr", "lpips")})
    return record


def run_name(run: str) -> str:
    """A run folder's most telling part (a benchmark's run folders end in method names)."""
    parts = Path(run).parts
    return next((p for p in reversed(parts) if "-" in p), parts[-1])


def table(records) -> str:
    keys = ("unseen", "outside", "partial", "white", "white_unseen")
    scored = all("lpips" in r["before"] for r in records)
    head = ["run"] + [f"{k} before / after" for k in keys] + (["PSNR before / after", "LPIPS before / after"]
                                                             if scored else [])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]

    def cells(r):
        out = [f"{100 * r['before'][k]:.2f}% / {100 * r['after'][k]:.2f}%" for k in keys]
        if scored:
            out += [f"{r['before']['psnr']:.2f} / {r['after']['psnr']:.2f}",
                    f"{r['before']['lpips']:.4f} / {r['after']['lpips']:.4f}"]
        return out

    lines.extend(f"| {run_name(r['run'])} | " + " | ".join(cells(r)) + " |" for r in records)
    mean = {part: {k: float(np.mean([r[part][k] for r in records])) for k in records[0][part]}
            for part in ("before", "after")}
    lines.append("| **mean** | " + " | ".join(cells(mean)) + " |")
    return "\n".join(lines)


@friendly_errors
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, nargs="+", required=True)
    parser.add_argument("--out", type=Path, required=True, help="JSON lines, one per run (appended)")
    parser.add_argument("--texture-size", type=int, default=1024)
    parser.add_argument("--score", action="store_true", help="also score the textured meshes on held-out views")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    done = keyed_rows(args.out, lambda row: row["run"])
    records = []
    for run in args.runs:
        record = done.get(str(run))
        if record is None or (args.score and "lpips" not in record["before"]):
            record = evaluate(run, args.texture_size, args.score)
            append_row(args.out, record)
        records.append(record)
        print(f"{run}: unseen {record['before']['unseen']:.4f} -> {record['after']['unseen']:.4f}, white "
              f"{record['before']['white']:.4f} -> {record['after']['white']:.4f}", file=sys.stderr)
    print(table(records))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
