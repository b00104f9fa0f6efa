"""How much a finished run's scores move when it trains on at its final learning rate: a copy of the run
folder continues step by step past its end, and the off-rig scores of ``run_all_views.py`` are taken at each
stop. Scores that move between nearby steps as much as a reseed moves them mean that the last step's
weights are one noisy draw, which averaging the last steps' weights (``average_fraction``) would steady.

    python benchmarks/late_iterates.py RUN_DIR --method neus --seed 42 [--steps 2025,2050,2100] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
import run_all_views  # a sibling script: its scoring


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path, help="a finished run of run_all_views.py or judge.py")
    parser.add_argument("--method", default="neus")
    parser.add_argument("--seed", type=int, default=42, help="the run's ray-sampler seed")
    parser.add_argument("--steps", default="2025,2050,2100", help="steps at which to score, comma-separated")
    parser.add_argument("--out", type=Path, default=None, help="the copy that trains on (default: RUN_DIR-late)")
    args = parser.parse_args(argv)
    import torch

    from va_plugin.config import apply_override
    from va_plugin.engine.trainer import train_run
    from va_plugin.registry import get_method

    torch.set_num_threads(1)
    if not (args.run_dir / "config.json").is_file():
        print(f"error: {args.run_dir} holds no run (no config.json)", file=sys.stderr)
        return 2
    out = args.out or args.run_dir.with_name(args.run_dir.name + "-late")
    if not out.exists():
        shutil.copytree(args.run_dir, out)
    scene = json.loads((args.run_dir / "config.json").read_text())["pipeline"]["datamanager"]["dataparser"]["data"]
    scores, state = run_all_views.score(str(out))
    print(json.dumps({"steps": int(state["step"]), **{k: scores[k] for k in ("psnr", "lpips", "cd", "iou")}}))
    for target in (int(s) for s in args.steps.split(",")):
        config = get_method(args.method).make_config()
        config.pipeline.datamanager.dataparser.data = Path(scene)
        config.output_dir, config.progress, config.max_steps = out, False, target
        apply_override(config, f"pipeline.datamanager.seed={args.seed}")
        train_run(config, resume=True)
        scores, _ = run_all_views.score(str(out))
        print(json.dumps({"steps": target, **{k: scores[k] for k in ("psnr", "lpips", "cd", "iou")}}), flush=True)
    return 0


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    raise SystemExit(main())
