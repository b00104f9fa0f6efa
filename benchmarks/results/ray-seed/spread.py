"""The run-to-run spread of paired rows: per metric, the standard deviation over objects of the change
between two rows files, the largest change, and the standard deviation that implies for a mean over N
objects (sd / sqrt(N)).

    python benchmarks/results/ray-seed/spread.py BASE_ROWS.jsonl OTHER_ROWS.jsonl [N]
"""
import json
import math
import statistics
import sys


def load(path):
    return {row["scene"]: row for row in map(json.loads, open(path))}


base, other = load(sys.argv[1]), load(sys.argv[2])
n_mean = int(sys.argv[3]) if len(sys.argv) > 3 else 10
scenes = sorted(set(base) & set(other))
changes = {"psnr (dB)": [other[s]["psnr"] - base[s]["psnr"] for s in scenes],
           "lpips": [other[s]["lpips"] - base[s]["lpips"] for s in scenes],
           "cd (ratio - 1)": [other[s]["cd"] / base[s]["cd"] - 1 for s in scenes]}
print(f"{len(scenes)} objects")
for name, values in changes.items():
    sd = statistics.stdev(values)
    print(f"{name}: sd {sd:.4f}, largest {max(values, key=abs):+.4f}, mean {statistics.mean(values):+.4f}; "
          f"sd of a {n_mean}-object mean of such changes {sd / math.sqrt(n_mean):.4f}")
