"""Step time of `neus` with and without the projected-area prior, interleaved in one process (blocks of 10
steps each, alternately) so that a busy machine slows both alike. Both train the same scene from the same
seed with the default config at the default budget; the prior starts at step 0 here, so every step pays it.
With RUN (a finished run folder of that scene), both start from its last checkpoint instead, to time the
late steps, where the object's outline (and so the share of the prior's rays that meet it) is final.
(benchmarks/bench_step_cost.py does the same for any variants, one step at a time, from untrained states or,
with --from-run, from a finished run; this script stays as the record of the figures taken with it.)
Usage: python step_cost.py SCENE_DIR [STEPS] [WEIGHT] [RUN]
"""
import sys
import time
from pathlib import Path

import numpy as np
import torch

from va_plugin.config import apply_override
from va_plugin.engine.trainer import load_checkpoint
from va_plugin.registry import get_method

torch.set_num_threads(1)
scene = Path(sys.argv[1])
steps = int(sys.argv[2]) if len(sys.argv) > 2 else 300
weight = sys.argv[3] if len(sys.argv) > 3 else "0.05"
run = Path(sys.argv[4]) if len(sys.argv) > 4 else None


def trainer(tag, overrides):
    config = get_method("neus").make_config()
    config.pipeline.datamanager.dataparser.data = scene
    config.output_dir = Path("/tmp/step_cost") / tag
    config.progress = False
    config.device = "cpu"
    for o in overrides:
        apply_override(config, o)
    torch.manual_seed(0)
    t = config.setup()
    if run is not None:
        t.load_state(load_checkpoint(run))
    return t


plain = trainer("plain", ["pipeline.model.projected_area_weight=0"])  # the default has the prior since 2026-11-26
prior = trainer("prior", [f"pipeline.model.projected_area_weight={weight}", "pipeline.model.projected_area_start=0"])
times = {"plain": [], "prior": []}
for block in range(steps // 10):
    for name, t in (("plain", plain), ("prior", prior)):
        start = time.perf_counter()
        for _ in range(10):
            t.run_step()
        times[name].append((time.perf_counter() - start) / 10)
skip = len(times["plain"]) // 5  # the first fifth is warm-up
a, b = np.median(times["plain"][skip:]), np.median(times["prior"][skip:])
print(f"{scene.name}: median step {a:.3f} s plain, {b:.3f} s with the prior at {weight}: x{b / a:.3f} "
      f"(steps {skip * 10}-{steps}{' after ' + run.name if run else ''})")
