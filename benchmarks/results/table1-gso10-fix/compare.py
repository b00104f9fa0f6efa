"""Paired `va-neus` against `neus` rows of one level (ad hoc, behind benchmarks/RESULTS.md, "Table 1 on
GSO-10 with the regularizer fix"):
    python benchmarks/results/table1-gso10-fix/compare.py NEUS.csv VA.csv [VA_OLD.csv]
Prints the per-object table (PSNR / LPIPS / CD / IoU), the paired means and, with VA_OLD (the same
variant before the fix), its column beside. Rows are matched by scene; the first row of a scene counts."""
import csv
import sys

import numpy as np


def load(path, method):
    rows = {}
    for r in csv.DictReader(open(path)):
        if r["method"] == method:
            rows.setdefault(r["scene"], r)
    return rows


neus = load(sys.argv[1], "neus")
va = load(sys.argv[2], "va-neus")
old = load(sys.argv[3], "va-neus") if len(sys.argv) > 3 else None
objs = [o for o in sorted(neus) if o in va and (old is None or o in old)]
tables = [neus, va] + ([old] if old is not None else [])


def cell(r):
    return f"{float(r['psnr']):.2f} / {float(r['lpips']):.3f} / {float(r['cd']):.4f} / {float(r['iou']):.3f}"


head = "| object | `neus` | `va-neus` (fix) |" + (" `va-neus` (joint loss) |" if old else "") + " fix against `neus` |"
print(head)
print("|---" * (head.count("|") - 1) + "|")
dp, rc = [], []
for o in objs:
    dp.append(float(va[o]["psnr"]) - float(neus[o]["psnr"]))
    rc.append(float(va[o]["cd"]) / float(neus[o]["cd"]))
    cells = " | ".join(cell(t[o]) for t in tables)
    print(f"| {o.replace('gso-', '')} | {cells} | {dp[-1]:+.2f} dB, CD {100 * (rc[-1] - 1):+.1f}% |")


def mean(rows, k):
    return np.mean([float(rows[o][k]) for o in objs])


print(f"| **mean ({len(objs)})** | " + " | ".join(
    f"{mean(t, 'psnr'):.2f} / {mean(t, 'lpips'):.3f} / {mean(t, 'cd'):.4f} / {mean(t, 'iou'):.3f}" for t in tables)
      + " | |")
dp, rc = np.array(dp), np.array(rc)
print(f"\nva-neus (fix) vs neus ({len(objs)} objects): dPSNR {dp.mean():+.3f} (better on {(dp > 0).sum()}), "
      f"CD x{np.exp(np.log(rc).mean()):.3f} (better on {(rc < 1).sum()}), dLPIPS "
      f"{mean(va, 'lpips') - mean(neus, 'lpips'):+.4f}, ratio of mean CDs {mean(va, 'cd') / mean(neus, 'cd'):.3f}")
if old is not None:
    do = np.array([float(va[o]["psnr"]) - float(old[o]["psnr"]) for o in objs])
    print(f"fix vs joint loss: dPSNR {do.mean():+.3f} (better on {(do > 0).sum()}), CD ratio of means "
          f"{mean(va, 'cd') / mean(old, 'cd'):.3f}")
