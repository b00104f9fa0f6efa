"""How small Adam's second moments of a run's hash table are: the share of table entries whose sqrt(v)
lies below each candidate epsilon, and the table's value quantiles.

    python benchmarks/results/adam-eps/adam_state.py RUN/checkpoints/step-0002000.ckpt
"""
import sys

import torch

checkpoint = torch.load(sys.argv[1], map_location="cpu", weights_only=False)
table_key = next(k for k in checkpoint["model"] if k.endswith("encoding.table"))
table = checkpoint["model"][table_key]
state = next(s for s in checkpoint["optimizer"]["state"].values() if s["exp_avg_sq"].shape == table.shape)
root = state["exp_avg_sq"].sqrt().flatten()
print(f"{table_key}: {tuple(table.shape)}; |value| mean {table.abs().mean():.3f}, median "
      f"{table.abs().flatten().median():.3f}")
for eps in (1e-10, 1e-9, 1e-8, 1e-7, 1e-6, 1e-5):
    print(f"sqrt(v) below {eps:.0e}: {float((root < eps).float().mean()):.3f} of the entries")
