"""Paired level-2 rows of two run_backbone rows files, per object and on the mean.

    python benchmarks/results/crossings/compare.py STEPS BASE_ROWS.jsonl BASE_VARIANT_PART NEW_ROWS.jsonl NEW_VARIANT_PART

A row is taken when its step count is STEPS and its variant name contains the given part. Prints one
table line per object (PSNR / LPIPS / CD / IoU of each, the change), then the mean changes, the CD ratio
of the means and the geometric mean of the per-object ratios, and how many objects improved.
"""
import json, sys, numpy as np
def load(f, steps, sub):
    out = {}
    for l in open(f):
        r = json.loads(l)
        if r["steps"] == steps and r["level"] == 2 and sub in r["variant"]:
            out[r["scene"][4:]] = r
    return out
steps = int(sys.argv[1])
base = load(sys.argv[2], steps, sys.argv[3])
new = load(sys.argv[4], steps, sys.argv[5])
acc = []
for s in sorted(new):
    if s not in base: continue
    b, r = base[s], new[s]
    dp, cr = r["psnr"] - b["psnr"], r["cd"] / b["cd"]
    acc.append((dp, cr, r["lpips"] - b["lpips"], r["iou"] - b["iou"], r["psnr"], r["lpips"], r["cd"], r["iou"], b["psnr"], b["lpips"], b["cd"], b["iou"]))
    print(f"| {s} | {b['psnr']:.2f} / {b['lpips']:.3f} / {b['cd']:.4f} / {b['iou']:.3f} | {r['psnr']:.2f} / {r['lpips']:.3f} / {r['cd']:.4f} / {r['iou']:.3f} | {dp:+.2f} dB, CD {100*(cr-1):+.1f}% |")
a = np.array(acc)
print(len(a), "objects; dPSNR %+.3f (higher %d); CD ratio of means x%.3f, geo x%.3f (better %d); dLPIPS %+.4f (better %d); dIoU %+.4f (better %d)" % (
    a[:,0].mean(), (a[:,0]>0).sum(), a[:,6].mean()/a[:,10].mean(), np.exp(np.log(a[:,1]).mean()), (a[:,1]<1).sum(), a[:,2].mean(), (a[:,2]<0).sum(), a[:,3].mean(), (a[:,3]>0).sum()))
print("means new %.2f / %.3f / %.4f / %.3f ; base %.2f / %.3f / %.4f / %.3f" % tuple(list(a[:,4:8].mean(0)) + list(a[:,8:12].mean(0))))
