"""The level-3 gap of `neus` split by inconsistency kind (ad hoc, behind benchmarks/RESULTS.md, "Where the level-3 gap comes from"):
    python benchmarks/results/l3-kinds-neus/gap_by_kind.py outputs/bench/l3-kinds/rows.jsonl
per object PSNR / LPIPS / CD at level 0, level 3 (all kinds) and level 3 with each set of kinds, and each set's share of the gap."""
import csv, json, sys
import numpy as np
def load_csv(path, variant="neus"):
    return {r["scene"]: r for r in csv.DictReader(open(path)) if r["variant"] == variant}
l0 = load_csv("benchmarks/results/backbone-gso10-l0/backbone.csv")
l3 = load_csv("benchmarks/results/table1-gso10-va-neus-l3/backbone.csv")
sets = {}
for path in sys.argv[1:]:
    for line in open(path):
        r = json.loads(line)
        base, _, kinds = r["scene"].partition("+")
        sets.setdefault(kinds, {})[base] = r
objs = sorted(l0)
print("| object | L0 | L3 all | " + " | ".join(f"L3 {k}" for k in sets) + " |")
def f(r): return f"{float(r['psnr']):.2f} / {float(r['lpips']):.3f} / {float(r['cd']):.4f}"
share = {k: {"psnr": [], "cd": [], "lpips": []} for k in sets}
for o in objs:
    cells = [f(l0[o]), f(l3[o])] + [f(sets[k][o]) if o in sets[k] else "-" for k in sets]
    print(f"| {o.replace('gso-','')} | " + " | ".join(cells) + " |")
print()
for k in sets:
    have = [o for o in objs if o in sets[k]]
    dp_all = np.array([float(l0[o]["psnr"]) - float(l3[o]["psnr"]) for o in have])
    dp_k = np.array([float(l0[o]["psnr"]) - float(sets[k][o]["psnr"]) for o in have])
    dc_all = np.array([float(l3[o]["cd"]) / float(l0[o]["cd"]) for o in have])
    dc_k = np.array([float(sets[k][o]["cd"]) / float(l0[o]["cd"]) for o in have])
    dl_all = np.array([float(l3[o]["lpips"]) - float(l0[o]["lpips"]) for o in have])
    dl_k = np.array([float(sets[k][o]["lpips"]) - float(l0[o]["lpips"]) for o in have])
    print(f"{k}: {len(have)} objects; PSNR cost {dp_k.mean():+.2f} dB of {dp_all.mean():+.2f} (share {dp_k.mean()/dp_all.mean():.2f}); "
          f"CD x{np.exp(np.log(dc_k).mean()):.3f} of x{np.exp(np.log(dc_all).mean()):.3f}; LPIPS {dl_k.mean():+.4f} of {dl_all.mean():+.4f}")
