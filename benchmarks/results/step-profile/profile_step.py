"""Where a `neus` training step goes: the stage breakdown and torch's operator profile, mid-run.

    python benchmarks/results/step-profile/profile_step.py SCENE_DIR [WARM_STEPS] [TIMED_STEPS] [THREADS] [KEY=VALUE ...]

Trains the `neus` default on SCENE_DIR (a run_backbone scene folder) for WARM_STEPS (default 600), then times
TIMED_STEPS (default 30) with the stage markers on (mean ms per step, exclusive stages) and profiles 10 more
with torch.profiler (top operators by self CPU time). KEY=VALUE are --set overrides (e.g.
pipeline.model.inv_s_floor=0). The run folder is a temporary one.
"""
import sys
import tempfile
import time
from pathlib import Path

import torch
from torch.profiler import ProfilerActivity, profile

from va_plugin.config import apply_override
from va_plugin.engine.trainer import Trainer
from va_plugin.registry import get_method
from va_plugin.utils.stages import recording

scene = sys.argv[1]
warm = int(sys.argv[2]) if len(sys.argv) > 2 else 600
timed = int(sys.argv[3]) if len(sys.argv) > 3 else 30
torch.set_num_threads(int(sys.argv[4]) if len(sys.argv) > 4 else 1)
config = get_method("neus").make_config(None)
config.pipeline.datamanager.dataparser.data = Path(scene)
config.output_dir = Path(tempfile.mkdtemp(prefix="profile-step-"))
config.progress = False
for assignment in sys.argv[5:]:
    apply_override(config, assignment)
trainer = Trainer(config)
for _ in range(warm):
    trainer.run_step()
with recording() as recorder:
    start = time.perf_counter()
    for _ in range(timed):
        trainer.run_step()
    seconds = time.perf_counter() - start
print(f"ms per step over steps {warm}-{warm + timed}: {1000 * seconds / timed:.1f}")
for name, value in sorted(recorder.exclusive.items(), key=lambda kv: -kv[1]):
    print(f"  {name:<16} {1000 * value / timed:7.1f}")
with profile(activities=[ProfilerActivity.CPU]) as prof:
    for _ in range(10):
        trainer.run_step()
print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=15))
