"""`neus` with per-view image warps (penalty 300) against `neus` on GSO-10 at level 3 (ad hoc, behind
benchmarks/RESULTS.md, "Per-view image warps"):
    python benchmarks/results/warp-l3/compare.py benchmarks/results/warp-l3/screen.csv benchmarks/results/warp-l3/screen2.csv benchmarks/results/warp-l3/backbone.csv
The `neus` rows are those of the given CSVs where present (alarm, bell: rerun beside the warps), else the
recorded level-3 table (benchmarks/results/table1-gso10-va-neus-l3); level 0 is benchmarks/results/backbone-gso10-l0.
Prints the per-object table, the paired means and the share of `neus`'s level-0 gap the warps close."""
import csv
import sys

import numpy as np

WARP = "neus@pipeline.model.view_warp.enabled=true@pipeline.model.view_warp.penalty_weight=300"


def load(path, variant):
    return {r["scene"]: r for r in csv.DictReader(open(path)) if r["variant"] == variant}


l0 = load("benchmarks/results/backbone-gso10-l0/backbone.csv", "neus")
base = load("benchmarks/results/table1-gso10-va-neus-l3/backbone.csv", "neus")
warp = {}
for path in sys.argv[1:]:
    base.update(load(path, "neus"))
    warp.update(load(path, WARP))
objs = [o for o in sorted(l0) if o in warp]


def cell(r):
    return f"{float(r['psnr']):.2f} / {float(r['lpips']):.3f} / {float(r['cd']):.4f} / {float(r['iou']):.3f}"


print("| object | `neus` level 0 | `neus` level 3 | warps level 3 | change |")
print("|---|---|---|---|---|")
dp, rc, dl, gap_p, gap_c = [], [], [], [], []
for o in objs:
    b, w, z = base[o], warp[o], l0[o]
    dp.append(float(w["psnr"]) - float(b["psnr"]))
    rc.append(float(w["cd"]) / float(b["cd"]))
    dl.append(float(w["lpips"]) - float(b["lpips"]))
    gap_p.append(float(z["psnr"]) - float(b["psnr"]))
    gap_c.append(float(b["cd"]) - float(z["cd"]))
    print(f"| {o.replace('gso-', '')} | {cell(z)} | {cell(b)} | {cell(w)} | {dp[-1]:+.2f} dB, CD {100 * (rc[-1] - 1):+.1f}% |")
dp, rc, dl = np.array(dp), np.array(rc), np.array(dl)
mean = lambda rows, k: np.mean([float(rows[o][k]) for o in objs])  # noqa: E731
print(f"| **mean ({len(objs)})** | " + " | ".join(
    f"{mean(t, 'psnr'):.2f} / {mean(t, 'lpips'):.3f} / {mean(t, 'cd'):.4f} / {mean(t, 'iou'):.3f}" for t in (l0, base, warp)) + " | |")
print(f"\nwarps vs neus at L3 ({len(objs)} objects): dPSNR {dp.mean():+.2f} (better {int((dp > 0).sum())}), "
      f"CD x{np.exp(np.log(rc).mean()):.3f} (better {int((rc < 1).sum())}), dLPIPS {dl.mean():+.4f} (better {int((dl < 0).sum())}); "
      f"share of the level-0 gap closed: PSNR {dp.sum() / np.sum(gap_p):.2f}, "
      f"CD {np.sum([float(base[o]['cd']) - float(warp[o]['cd']) for o in objs]) / np.sum(gap_c):.2f}")
