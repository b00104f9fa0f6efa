"""Textured-mesh scores of run_texture.py lines against those of earlier runs.

    python benchmarks/results/crossings/texture_compare.py TEXTURE.jsonl [BASE_TEXTURE.jsonl]

BASE_TEXTURE defaults to the projected-area prior's runs (benchmarks/results/projected-area/texture-l2.jsonl).
One table line per object: field PSNR / LPIPS, textured (robust fusion) PSNR / LPIPS, textured (plain mean)
LPIPS, and the base runs' textured (robust) PSNR / LPIPS; then the means and counts.
"""
import json, re, sys, numpy as np
def load(f):
    out = {}
    for l in open(f):
        r = json.loads(l); out[re.search(r"gso-([a-z]+)-l2", r["run"]).group(1)] = r
    return out
base = load(sys.argv[2] if len(sys.argv) > 2 else "benchmarks/results/projected-area/texture-l2.jsonl")
new = load(sys.argv[1])
acc = []
for n in sorted(new):
    if n not in base:
        continue
    r, b = new[n], base[n]
    acc.append((r["field"]["lpips"], r["robust"]["lpips"], r["mean"]["lpips"], b["robust"]["lpips"], r["robust"]["psnr"], b["robust"]["psnr"]))
    print(f"| {n} | {r['field']['psnr']:.2f} / {r['field']['lpips']:.4f} | {r['robust']['psnr']:.2f} / {r['robust']['lpips']:.4f} | {r['mean']['lpips']:.4f} | {b['robust']['psnr']:.2f} / {b['robust']['lpips']:.4f} |")
a = np.array(acc); m = a.mean(0)
print(f"| **mean ({len(a)})** | {m[0]:.4f} | {m[4]:.2f} / {m[1]:.4f} | {m[2]:.4f} | {m[5]:.2f} / {m[3]:.4f} |")
print("median robust %.4f; under .12: %d; better than field %d; robust<mean %d (%+.4f); better than base tex %d" % (
    np.median(a[:,1]), (a[:,1] <= .12).sum(), (a[:,1] < a[:,0]).sum(), (a[:,1] < a[:,2]).sum(), (a[:,1]-a[:,2]).mean(), (a[:,1] < a[:,3]).sum()))
