"""Textured meshes and field renders under the same pixel sampling: one table line per object.

    python benchmarks/results/texture-sampling/table.py TEXTURE.jsonl [FIELD_2X2.jsonl]

TEXTURE.jsonl: run_texture.py lines of the same runs at ``--supersample 1`` and ``--supersample 2``.
FIELD_2X2.jsonl: the field's held-out renders averaged over 2x2 rays a pixel, one line per run
(``{"run": RUN, "ss": {"psnr", "ssim", "lpips"}}``). Columns (PSNR / LPIPS): the field (one ray a pixel),
the textured mesh with robust fusion at one ray a pixel and at 2x2, the plain mean at one ray a pixel, and
the field at 2x2 where given; then the means and counts over the objects that have both textured settings.
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from texture_lines import load, object_name as name  # noqa: E402

USAGE = "usage: python table.py TEXTURE.jsonl [FIELD_2X2.jsonl]"
if len(sys.argv) not in (2, 3) or not all(Path(p).is_file() for p in sys.argv[1:]):
    sys.exit(USAGE)
by = {}
for r in load(sys.argv[1]):
    by.setdefault(name(r["run"]), {})[r.get("supersample", 2)] = r
field2 = {}
if len(sys.argv) == 3:
    for r in load(sys.argv[2]):
        field2[name(r["run"])] = r["ss"]
objects = sorted(n for n, s in by.items() if 1 in s and 2 in s)
if not objects:
    sys.exit(f"{sys.argv[1]} holds no run scored at both --supersample 1 and 2")
print("| object | field, 1 ray | textured, 1 ray | textured, 2x2 | plain mean, 1 ray | field, 2x2 |")
print("|---|---|---|---|---|---|")
acc = []
for n in objects:
    one, two = by[n][1], by[n][2]
    f2 = field2.get(n)
    cell = lambda s: f"{s['psnr']:.2f} / {s['lpips']:.4f}"  # noqa: E731
    print(f"| {n} | {cell(one['field'])} | {cell(one['robust'])} | {cell(two['robust'])} | "
          f"{one['mean']['lpips']:.4f} | {cell(f2) if f2 else '-'} |")
    acc.append([one["field"]["psnr"], one["field"]["lpips"], one["robust"]["psnr"], one["robust"]["lpips"],
                two["robust"]["psnr"], two["robust"]["lpips"], one["mean"]["lpips"],
                f2["lpips"] if f2 else np.nan])
a = np.array(acc)
m = a.mean(0)
print(f"| **mean ({len(a)})** | {m[0]:.2f} / {m[1]:.4f} | {m[2]:.2f} / {m[3]:.4f} | {m[4]:.2f} / {m[5]:.4f} | "
      f"{m[6]:.4f} | |")
print(f"textured better than the field (LPIPS), both one ray a pixel: {(a[:, 3] < a[:, 1]).sum()}/{len(a)}; "
      f"textured at 2x2 against the field at one ray (the comparison before 2026-11-28): {(a[:, 5] < a[:, 1]).sum()}/{len(a)}")
both = ~np.isnan(a[:, 7])
if both.any():
    print(f"both at 2x2: textured better on {(a[both, 5] < a[both, 7]).sum()}/{both.sum()} "
          f"(field {a[both, 7].mean():.4f}, textured {a[both, 5].mean():.4f})")
print(f"textured LPIPS, one ray: median {np.median(a[:, 3]):.4f}, under 0.12 on {(a[:, 3] <= 0.12).sum()}/{len(a)}; "
      f"robust better than the plain mean on {(a[:, 3] < a[:, 6]).sum()}/{len(a)} ({(a[:, 3] - a[:, 6]).mean():+.4f})")
