"""Textured-mesh scores of run_texture.py lines against those of earlier runs.

    python benchmarks/results/crossings/texture_compare.py TEXTURE.jsonl [BASE_TEXTURE.jsonl]

BASE_TEXTURE defaults to the projected-area prior's runs (benchmarks/results/projected-area/texture-l2.jsonl).
One table line per object: field PSNR / LPIPS, textured (robust fusion) PSNR / LPIPS, textured (plain mean)
LPIPS, and the base runs' textured (robust) PSNR / LPIPS; then the means and counts. With ``-`` as
BASE_TEXTURE there is no base: the last column is robust fusion's LPIPS minus the plain mean's, and the
largest such difference is printed (issue 20's level-0 check: equal within 0.005).
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from texture_lines import by_object  # noqa: E402

if len(sys.argv) not in (2, 3):
    sys.exit("usage: python texture_compare.py TEXTURE.jsonl [BASE_TEXTURE.jsonl]")
new = by_object(sys.argv[1])
if not new:
    sys.exit(f"{sys.argv[1]} holds no run_texture.py line")
if len(sys.argv) == 3 and sys.argv[2] == "-":
    print("| object | field | textured, robust | plain mean (LPIPS) | robust - mean |")
    print("|---|---|---|---|---|")
    gaps = []
    for n in sorted(new):
        r = new[n]
        gaps.append((r["robust"]["lpips"] - r["mean"]["lpips"], r["robust"]["lpips"] < r["field"]["lpips"]))
        print(f"| {n} | {r['field']['psnr']:.2f} / {r['field']['lpips']:.4f} | {r['robust']['psnr']:.2f} / "
              f"{r['robust']['lpips']:.4f} | {r['mean']['lpips']:.4f} | {gaps[-1][0]:+.4f} |")
    g = np.array([x for x, _ in gaps])
    print(f"robust within 0.005 of the plain mean on {(np.abs(g) <= 0.005).sum()}/{len(g)} (largest {g[np.argmax(np.abs(g))]:+.4f}, "
          f"mean {g.mean():+.4f}); textured better than the field on {sum(w for _, w in gaps)}/{len(g)}")
    sys.exit(0)
base = by_object(sys.argv[2] if len(sys.argv) > 2 else "benchmarks/results/projected-area/texture-l2.jsonl")
acc = []
for n in sorted(new):
    if n not in base:
        continue
    r, b = new[n], base[n]
    acc.append((r["field"]["lpips"], r["robust"]["lpips"], r["mean"]["lpips"], b["robust"]["lpips"], r["robust"]["psnr"], b["robust"]["psnr"]))
    print(f"| {n} | {r['field']['psnr']:.2f} / {r['field']['lpips']:.4f} | {r['robust']['psnr']:.2f} / {r['robust']['lpips']:.4f} | {r['mean']['lpips']:.4f} | {b['robust']['psnr']:.2f} / {b['robust']['lpips']:.4f} |")
if not acc:
    sys.exit("no object in both files")
a = np.array(acc); m = a.mean(0)
print(f"| **mean ({len(a)})** | {m[0]:.4f} | {m[4]:.2f} / {m[1]:.4f} | {m[2]:.4f} | {m[5]:.2f} / {m[3]:.4f} |")
print("median robust %.4f; under .12: %d; better than field %d; robust<mean %d (%+.4f); better than base tex %d" % (
    np.median(a[:,1]), (a[:,1] <= .12).sum(), (a[:,1] < a[:,0]).sum(), (a[:,1] < a[:,2]).sum(), (a[:,1]-a[:,2]).mean(), (a[:,1] < a[:,3]).sum()))
