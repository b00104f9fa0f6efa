"""Per-object held-out PSNR / LPIPS of run_texture.py lines with the field-colour bakes (issue 20).

    python benchmarks/results/texture-field-prior/compare.py FILE.jsonl [FILE.jsonl ...]

Columns: the field's renders, robust fusion, the plain mean, and every other bake the lines hold (e.g.
robust-field=W, robust-anchor=W), in their order; then the means and, per bake, on how many objects it
beats the field and robust fusion.
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from texture_lines import load, object_name  # noqa: E402

if len(sys.argv) < 2:
    sys.exit("usage: python compare.py FILE.jsonl [FILE.jsonl ...]")
lines = load(sys.argv[1])
if not lines:
    sys.exit(f"{sys.argv[1]} holds no run_texture.py line")
first = lines[0]
keys = ['field'] + [k for k, v in first.items() if isinstance(v, dict) and 'lpips' in v and k != 'field']
rows = []
print('| object | ' + ' | '.join(keys) + ' |')
print('|---' * (len(keys) + 1) + '|')
for f in sys.argv[1:]:
    for r in load(f):
        n = object_name(r['run'])
        rows.append([r[k]['lpips'] for k in keys] + [r[k]['psnr'] for k in keys])
        print(f'| {n} | ' + ' | '.join(f"{r[k]['psnr']:.2f} / {r[k]['lpips']:.4f}" for k in keys) + ' |')
a = np.array(rows); m = a.mean(0); K = len(keys)
print('| **mean** | ' + ' | '.join(f"{m[K + i]:.2f} / {m[i]:.4f}" for i in range(K)) + ' |')
for i, k in enumerate(keys[1:], 1):
    print(f"{k}: better than the field on {(a[:, i] < a[:, 0]).sum()}/{len(a)}, than robust on "
          f"{(a[:, i] < a[:, 1]).sum()}/{len(a)} ({(a[:, i] - a[:, 1]).mean():+.4f}), median {np.median(a[:, i]):.4f}, "
          f"<= 0.12 on {(a[:, i] <= .12).sum()}")
