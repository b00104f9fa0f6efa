"""Seconds per ``neus`` training step with the SDF gradient by double backward and by the analytic path.

    python benchmarks/bench_sdf_gradient.py [--load RUN] [--steps 10] [--repeats 2] [--threads 1]
        [--data DIR] [--set PATH=VALUE ...] [--out benchmarks/results/sdf_gradient.json]

Each mode runs in its own process (autograd, analytic, autograd, ... ``--repeats`` times each): in one
shared process the allocator's state left by one mode changes the page faults, and so the time, of the
other. A process builds the default ``neus`` trainer on the scene (the embedded default scene without
``--data``), loads the model and optimizer of ``--load`` when given (a trained state: fewer rays reach
the surface, fewer samples per ray), then times ``--steps`` training steps, each from that same state on
the same batch sequence. Per step it records the thread's CPU time (robust to other jobs on a shared
machine), wall time, minor page faults, and the CPU time of each stage: sampling (coarse SDF probes and
up-sampling, no graph), the SDF with its gradient, the colour network, the rest of the forward pass,
backward and the optimizer. Medians per mode (over all its processes) go into the JSON.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Callable, Dict, List

import torch

MODES = ("autograd", "analytic")
STAGES = ("sampling", "sdf_and_gradient", "color", "other_forward", "backward", "optimizer")


def _timer(store: Dict[str, float], name: str, fn: Callable) -> Callable:
    def wrapper(*args, **kwargs):
        start = time.thread_time()
        try:
            return fn(*args, **kwargs)
        finally:
            store[name] += time.thread_time() - start
    return wrapper


def worker(mode: str, args: argparse.Namespace) -> List[dict]:
    """Time ``args.steps`` steps of one mode in this process."""
    from va_plugin.cli.train import build_parser, make_config
    from va_plugin.engine.trainer import load_checkpoint
    from va_plugin.registry import discover_methods

    torch.set_num_threads(args.threads)
    methods = discover_methods()
    argv = ["neus", "--output-dir", str(args.work), "--no-progress",
            "--set", f"pipeline.model.sdf_gradient={mode}", "--set", f"num_threads={args.threads}"]
    if args.data is not None:
        argv += ["--data", str(args.data)]
    for assignment in args.overrides:
        argv += ["--set", assignment]
    trainer = make_config(build_parser(methods).parse_args(argv), methods).setup()
    if args.load is not None:
        state = load_checkpoint(args.load)
        trainer.model.load_state_dict(state["model"])
        trainer.optimizer.load_state_dict(state["optimizer"])
        trainer.step = int(state["step"]) - 1
    model, datamanager = trainer.model, trainer.pipeline.datamanager
    spent: Dict[str, float] = defaultdict(float)
    model._coarse = _timer(spent, "sampling", model._coarse)
    model._sample_edges = _timer(spent, "sampling", model._sample_edges)
    model._render = _timer(spent, "render", model._render)
    model.field.color = _timer(spent, "color", model.field.color)
    if mode == "analytic":
        model.field.geometry_and_gradient = _timer(spent, "sdf_and_gradient", model.field.geometry_and_gradient)
    else:  # the field's forward with grad mode on, and autograd.grad, both inside _render
        probe = model.field.geometry
        model.field.geometry = lambda x: _timer(spent, "sdf_and_gradient" if torch.is_grad_enabled() else "probe",
                                                probe)(x)
        torch.autograd.grad = _timer(spent, "sdf_and_gradient", torch.autograd.grad)
    model_state = copy.deepcopy(model.state_dict())
    optimizer_state = copy.deepcopy(trainer.optimizer.state_dict())
    generator = torch.Generator().manual_seed(0)
    rows = []
    for index in range(args.steps + 1):  # the first step warms up
        torch.manual_seed(int(torch.randint(0, 2 ** 31, (1,), generator=generator)))
        datamanager.generator.manual_seed(index)
        model.load_state_dict(model_state)
        trainer.optimizer.load_state_dict(optimizer_state)
        spent.clear()
        faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        wall, cpu = time.perf_counter(), time.thread_time()
        trainer.optimizer.zero_grad(set_to_none=True)
        loss_dict, _ = trainer.pipeline.train_step(trainer.step)
        loss = sum(loss_dict.values())
        forward = time.thread_time()
        loss.backward()
        backward = time.thread_time()
        trainer.optimizer.step()
        end = time.thread_time()
        row = {"step_cpu": end - cpu, "step_wall": time.perf_counter() - wall, "backward": backward - forward,
               "optimizer": end - backward, "sampling": spent["sampling"],
               "sdf_and_gradient": spent["sdf_and_gradient"], "color": spent["color"],
               "minor_page_faults": resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults,
               "samples_per_ray": model.samples_per_ray, "loss": float(loss.detach())}
        row["other_forward"] = (forward - cpu) - row["sampling"] - row["sdf_and_gradient"] - row["color"]
        if index > 0:
            rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--load", type=Path, default=None, help="run folder whose checkpoint is the state timed")
    parser.add_argument("--data", type=Path, default=None, help="scene (default: the embedded default scene)")
    parser.add_argument("--steps", type=int, default=10, help="timed steps per process")
    parser.add_argument("--repeats", type=int, default=2, help="processes per mode, alternating")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="PATH=VALUE",
                        help="config override for both modes, as in va-train")
    parser.add_argument("--work", type=Path, default=Path("/tmp/va-bench-sdf-gradient"))
    parser.add_argument("--out", type=Path, default=None, help="JSON file for the results")
    parser.add_argument("--worker", choices=MODES, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker is not None:
        print(json.dumps(worker(args.worker, args)))
        return
    rows: Dict[str, List[dict]] = {mode: [] for mode in MODES}
    passthrough = ["--steps", str(args.steps), "--threads", str(args.threads), "--work", str(args.work)]
    for flag, value in (("--load", args.load), ("--data", args.data)):
        passthrough += [flag, str(value)] if value is not None else []
    for assignment in args.overrides:
        passthrough += ["--set", assignment]
    for repeat in range(args.repeats):
        for mode in MODES if repeat % 2 == 0 else MODES[::-1]:
            result = subprocess.run([sys.executable, __file__, "--worker", mode, *passthrough],
                                    check=True, capture_output=True, text=True)
            rows[mode].extend(json.loads(result.stdout.strip().splitlines()[-1]))
    keys = ("step_cpu", "step_wall") + STAGES + ("minor_page_faults", "samples_per_ray", "loss")
    median = {mode: {k: round(statistics.median(r[k] for r in rs), 4) for k in keys} for mode, rs in rows.items()}
    speedup = median["autograd"]["step_cpu"] / max(median["analytic"]["step_cpu"], 1e-9)
    for mode in MODES:
        print(f"{mode:9s} " + "  ".join(f"{k} {median[mode][k]}" for k in keys))
    print(f"analytic speed-up (CPU time per step): {speedup:.3f}x")
    if args.out is not None:
        report = {"command": "python benchmarks/bench_sdf_gradient.py " + " ".join(sys.argv[1:]),
                  "machine": {"cpus": os.cpu_count(), "threads": args.threads, "platform": platform.platform(),
                              "torch": torch.__version__, "load_average": list(os.getloadavg())},
                  "median": median, "speedup": round(speedup, 3), "steps": rows}
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=1), encoding="utf-8")


if __name__ == "__main__":
    main()
