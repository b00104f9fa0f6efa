"""Per-object table of longer budgets against their 1x rows: held-out PSNR, LPIPS and CD changes.

Usage: python compare.py BASE_ROWS LABEL ROWS[,ROWS...] [LABEL ROWS[,ROWS...] ...]

BASE_ROWS and each ROWS are run_backbone.py rows.jsonl files (the last row of a scene wins); a column's
mean is over the objects it has, with how many are within the issue's tolerance (PSNR no lower than
-0.2 dB, CD no higher than +3%). Below the table, one line per column: the means of both over its objects,
the geometric mean of the CD ratios, and on how many objects each metric is better.
"""
import json
import math
import sys


def load(paths):
    rows = {}
    for path in paths.split(","):
        for line in open(path):
            row = json.loads(line)
            rows[row["scene"]] = row
    return rows


base = load(sys.argv[1])
columns = [(sys.argv[i], load(sys.argv[i + 1])) for i in range(2, len(sys.argv), 2)]
print("| object | 1x PSNR / LPIPS / CD | " + " | ".join(label for label, _ in columns) + " |")
print("|---" * (2 + len(columns)) + "|")
sums = {label: [] for label, _ in columns}
for scene, b in sorted(base.items()):
    cells = [scene.replace("gso-", ""), f"{b['psnr']:.2f} / {b['lpips']:.3f} / {b['cd']:.4f}"]
    for label, rows in columns:
        r = rows.get(scene)
        if r is None:
            cells.append("-")
            continue
        d_psnr, d_lpips, d_cd = r["psnr"] - b["psnr"], r["lpips"] - b["lpips"], r["cd"] / b["cd"] - 1
        sums[label].append((d_psnr, d_lpips, d_cd))
        cells.append(f"{d_psnr:+.2f} dB, {d_lpips:+.3f}, CD {100 * d_cd:+.1f}%")
    print("| " + " | ".join(cells) + " |")
cells = ["**mean**", ""]
for label, _ in columns:
    got = sums[label]
    if not got:
        cells.append("-")
        continue
    n = len(got)
    ok_psnr = sum(d[0] >= -0.2 for d in got)
    ok_cd = sum(d[2] <= 0.03 for d in got)
    cells.append(f"{sum(d[0] for d in got) / n:+.2f} dB, {sum(d[1] for d in got) / n:+.3f}, "
                 f"CD {100 * sum(d[2] for d in got) / n:+.1f}% ({n} objects; PSNR in tolerance {ok_psnr}/{n}, "
                 f"CD {ok_cd}/{n})")
print("| " + " | ".join(cells) + " |")

METRICS = ("psnr", "lpips", "cd", "iou", "ssim")
for label, rows in columns:
    both = [(base[s], rows[s]) for s in sorted(base) if s in rows]
    if not both:
        continue
    means = [" / ".join(f"{sum(pair[i][k] for pair in both) / len(both):.4g}" for k in METRICS) for i in (0, 1)]
    geo = math.exp(sum(math.log(r["cd"] / b["cd"]) for b, r in both) / len(both))
    better = {k: sum((r[k] < b[k]) if k in ("lpips", "cd") else (r[k] > b[k]) for b, r in both) for k in METRICS}
    print(f"{label}: {len(both)} objects; means {'/'.join(METRICS)} {means[0]} -> {means[1]}; CD geometric mean "
          f"x{geo:.3f}; better on " + ", ".join(f"{k} {v}" for k, v in better.items()))
