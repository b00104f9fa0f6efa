"""Micro-benchmark of the hash grid encoding on CPU: reference vs fast path, and backward strategies.

Times forward and forward+backward at N = 2**16 points (median of 5 runs after 2 warm-ups) for
T = 2**17 and 2**19, L = 16, F = 2; times the candidate scatters for the table gradient on the
encoding's real corner indices; sweeps the CPU chunk size; and measures what autograd keeps for the
backward pass. Writes everything to a JSON file.

    python benchmarks/bench_hash_grid.py [--out benchmarks/results/hash_grid.json] [--threads 2]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path
from typing import Callable, Dict

import torch

from va_plugin.fields.encodings import hash_grid
from va_plugin.fields.encodings.hash_grid import HashGridEncoding, encode_points, normalise_points
from va_plugin.fields.encodings.hash_grid_reference import hash_grid_reference

N_POINTS = 2**16
LOG2_TABLE_SIZES = (17, 19)
CHUNK_SIZES = (4096, 16384, N_POINTS)


def median_ms(fn: Callable[[], object], repeats: int = 5, warmups: int = 2) -> float:
    """Median wall-clock milliseconds of ``fn`` over ``repeats`` runs after ``warmups`` runs."""
    for _ in range(warmups):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return round(1e3 * statistics.median(times), 1)


def reference(encoding: HashGridEncoding) -> Callable[[torch.Tensor], torch.Tensor]:
    """The loop-based reference implementation on the encoding's table."""
    tables = (encoding.table, encoding.offsets, encoding.resolutions, encoding.hashmap_size, encoding.bound)
    return lambda x: hash_grid_reference(x, *tables)


def plain(encoding: HashGridEncoding) -> Callable[[torch.Tensor], torch.Tensor]:
    """The fast path's vectorised encoding, unchunked and differentiated by plain autograd."""
    return lambda x: encode_points(normalise_points(x, encoding.bound), encoding.table, encoding.levels())


def forward_and_backward(encode: Callable[[torch.Tensor], torch.Tensor], x: torch.Tensor, table: torch.Tensor):
    """Callables for a no-grad forward, forward+backward to the table, and to the table and ``x``."""

    def forward() -> None:
        with torch.no_grad():
            encode(x)

    def backward_table() -> None:
        torch.autograd.grad(encode(x).square().sum(), table)

    def backward_table_and_x() -> None:
        x_grad = x.detach().requires_grad_()
        torch.autograd.grad(encode(x_grad).square().sum(), (table, x_grad))

    return {"forward": forward, "fwd+bwd": backward_table, "fwd+bwd_with_x": backward_table_and_x}


def time_implementations(encoding: HashGridEncoding, x: torch.Tensor) -> Dict[str, Dict[str, float]]:
    """Milliseconds of the reference, plain autograd of the vectorised encoding, and the fast path.

    The reference's input-gradient run is skipped: it costs as much as its table-gradient run, which
    is dominated by one full-table accumulation per level and corner.
    """
    table = encoding.table
    implementations = {"reference": reference(encoding), "vectorised_plain_autograd": plain(encoding), "fast": encoding}
    results = {}
    for name, encode in implementations.items():
        stages = forward_and_backward(encode, x, table)
        if name == "reference":
            del stages["fwd+bwd_with_x"]
        results[name] = {stage: median_ms(fn) for stage, fn in stages.items()}
    return results


def time_scatters(encoding: HashGridEncoding, x: torch.Tensor) -> Dict[str, float]:
    """Milliseconds of each way to accumulate one gradient row per corner into a zero table gradient."""
    levels = encoding.levels()
    indices = (encoding.corner_indices(x).permute(1, 2, 0) + levels.offsets[:, None, None]).reshape(-1)
    rows = torch.randn(indices.shape[0], encoding.n_features_per_level)
    table = encoding.table.detach()

    def bincount() -> torch.Tensor:
        columns = [torch.bincount(indices, rows[:, f], minlength=table.shape[0]) for f in range(rows.shape[1])]
        return torch.stack(columns, 1).to(table.dtype)

    def sort_then_index_add() -> torch.Tensor:
        order = indices.argsort()
        return torch.zeros_like(table).index_add_(0, indices[order], rows[order])

    # The fast path produces its gradient rows feature-major, so the transpose is not timed.
    rows_by_feature = rows.t().contiguous()

    def index_add_columns() -> torch.Tensor:
        grad = torch.zeros_like(table)
        grad.t().index_add_(1, indices, rows_by_feature)
        return grad

    candidates = {
        "index_add_columns (used)": index_add_columns,
        "index_add_": lambda: torch.zeros_like(table).index_add_(0, indices, rows),
        "index_put_accumulate": lambda: torch.zeros_like(table).index_put_((indices,), rows, accumulate=True),
        "scatter_add_": lambda: torch.zeros_like(table).scatter_add_(0, indices[:, None].expand_as(rows), rows),
        "bincount_per_feature": bincount,
        "sort_then_index_add_": sort_then_index_add,
    }
    return {name: median_ms(fn) for name, fn in candidates.items()}


def saved_for_backward_mb(encoding: HashGridEncoding, x: torch.Tensor) -> Dict[str, float]:
    """MB that autograd keeps for the backward pass (table and point gradients), the table excluded."""
    table_storage = encoding.table.untyped_storage().data_ptr()
    implementations = {"vectorised_plain_autograd": plain(encoding), "fast": encoding}
    results = {}
    for name, encode in implementations.items():
        storages = {}

        def pack(tensor: torch.Tensor) -> torch.Tensor:
            storage = tensor.untyped_storage()
            if storage.data_ptr() != table_storage:
                storages[storage.data_ptr()] = storage.nbytes()
            return tensor

        with torch.autograd.graph.saved_tensors_hooks(pack, lambda tensor: tensor):
            encode(x.detach().requires_grad_())
        results[name] = round(sum(storages.values()) / 2**20, 1)
    return results


def time_chunk_sizes(encoding: HashGridEncoding, x: torch.Tensor) -> Dict[str, float]:
    """Fast-path forward+backward milliseconds for several CPU chunk sizes."""
    default = hash_grid.CPU_CHUNK_POINTS
    results = {}
    try:
        for chunk in CHUNK_SIZES:
            hash_grid.CPU_CHUNK_POINTS = chunk
            results[str(chunk)] = median_ms(forward_and_backward(encoding, x, encoding.table)["fwd+bwd"])
    finally:
        hash_grid.CPU_CHUNK_POINTS = default
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/hash_grid.json"))
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    x = torch.rand(N_POINTS, 3) * 2.0 - 1.0
    report = {
        "n_points": N_POINTS,
        "threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "load_average_before": os.getloadavg(),
        "runs": {},
    }
    for log2_size in LOG2_TABLE_SIZES:
        encoding = HashGridEncoding(log2_hashmap_size=log2_size)
        run = {
            "implementations_ms": time_implementations(encoding, x),
            "table_gradient_scatter_ms": time_scatters(encoding, x),
            "fast_fwd+bwd_by_cpu_chunk_ms": time_chunk_sizes(encoding, x),
            "saved_for_backward_mb": saved_for_backward_mb(encoding, x),
        }
        report["runs"][f"T=2^{log2_size}"] = run
        print(f"T=2^{log2_size}, N={N_POINTS}, threads={torch.get_num_threads()}", flush=True)
        for name, stages in run["implementations_ms"].items():
            print(f"  {name:26s} " + "  ".join(f"{k} {v:8.1f} ms" for k, v in stages.items()), flush=True)
        for title, key, unit in (
            ("table-gradient scatter", "table_gradient_scatter_ms", "ms"),
            ("fast fwd+bwd by chunk", "fast_fwd+bwd_by_cpu_chunk_ms", "ms"),
            ("saved for backward", "saved_for_backward_mb", "MB"),
        ):
            print(f"  {title}: " + ", ".join(f"{k} {v} {unit}" for k, v in run[key].items()))
    report["load_average_after"] = os.getloadavg()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
