"""`va-neus` against `neus` on GSO-10 at level 0, both with their defaults (ad hoc, behind
benchmarks/RESULTS.md, "`va-neus` at level 0 on GSO-10"):
    python benchmarks/results/va-neus-l0/compare.py benchmarks/results/va-neus-l0/backbone.csv
The `neus` rows are the recorded level-0 table (benchmarks/results/backbone-gso10-l0, deterministic).
Prints the per-object table, whether the adaptive phases ran, and the paired means against issue 21's
level-0 target (CD within 2%, PSNR within 0.1 dB)."""
import csv
import sys

import numpy as np


def load(path, variant):
    return {r["scene"]: r for r in csv.DictReader(open(path)) if r["variant"] == variant}


neus = load("benchmarks/results/backbone-gso10-l0/backbone.csv", "neus")
va = load(sys.argv[1], "va-neus")
objs = [o for o in sorted(neus) if o in va]


def cell(r):
    return f"{float(r['psnr']):.2f} / {float(r['lpips']):.3f} / {float(r['cd']):.4f} / {float(r['iou']):.3f}"


print("| object | `neus` | `va-neus` | adaptive phases | change |")
print("|---|---|---|---|---|")
dp, rc = [], []
for o in objs:
    b, v = neus[o], va[o]
    dp.append(float(v["psnr"]) - float(b["psnr"]))
    rc.append(float(v["cd"]) / float(b["cd"]))
    ran = v.get("adaptive_ran", v.get("adaptive phases ran", ""))
    print(f"| {o.replace('gso-', '')} | {cell(b)} | {cell(v)} | {ran} | {dp[-1]:+.2f} dB, CD {100 * (rc[-1] - 1):+.1f}% |")
mean = lambda rows, k: np.mean([float(rows[o][k]) for o in objs])  # noqa: E731
print(f"| **mean ({len(objs)})** | " + " | ".join(
    f"{mean(t, 'psnr'):.2f} / {mean(t, 'lpips'):.3f} / {mean(t, 'cd'):.4f} / {mean(t, 'iou'):.3f}" for t in (neus, va))
      + " | | |")
dp, rc = np.array(dp), np.array(rc)
print(f"\nva-neus vs neus at L0 ({len(objs)} objects): dPSNR {dp.mean():+.3f} (worst {dp.min():+.2f}), "
      f"CD x{np.exp(np.log(rc).mean()):.3f} (worst x{rc.max():.3f}); ratio of means CD "
      f"{mean(va, 'cd') / mean(neus, 'cd'):.3f}")
