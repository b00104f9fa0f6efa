"""Does this machine repeat a reference run's training bit for bit? A quick check before pairing new rows
with rows from an earlier session (runs repeat bit for bit on one machine but not across machines, see
RESULTS "Same code, same seed: runs repeat bit for bit").

Usage: python same_bits.py REFERENCE_RUN SCENE_DIR [STEPS]

REFERENCE_RUN is a training folder of a default run (its config.json and metrics.jsonl; for example
``outputs/bench/X/runs/SCENE/neus/neus``), SCENE_DIR the scene it trained on. The same method is trained
again with one torch thread at the reference's budget and seed, and its logged losses are compared with the
reference's, line by line, up to STEPS (default 500); the training is stopped there. Overrides the
reference run had (``--set``) are not repeated, so use a run of a method's defaults. Prints where the two
first differ, or that they agree; exit 0 when they agree, 1 when not.
"""
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

USAGE = "usage: python same_bits.py REFERENCE_RUN SCENE_DIR [STEPS]"
if len(sys.argv) not in (3, 4) or (len(sys.argv) == 4 and not sys.argv[3].isdigit()):
    sys.exit(USAGE)
ref, scene = Path(sys.argv[1]), Path(sys.argv[2])
limit = int(sys.argv[3]) if len(sys.argv) == 4 else 500
for path in (ref / "config.json", ref / "metrics.jsonl"):
    if not path.is_file():
        sys.exit(f"{path} is missing: REFERENCE_RUN must be a training folder (config.json, metrics.jsonl)")
if not scene.is_dir():
    sys.exit(f"{scene} is not a scene folder")
config = json.loads((ref / "config.json").read_text())
reference = [json.loads(line) for line in (ref / "metrics.jsonl").read_text().splitlines() if line.strip()]
reference = [r for r in reference if "loss" in r and r.get("step", limit + 1) <= limit]
if not reference:
    sys.exit(f"{ref / 'metrics.jsonl'} logs no training loss up to step {limit}")

out = Path(tempfile.mkdtemp(prefix="same-bits-"))
command = [sys.executable, "-m", "va_plugin.cli.train", config["method_name"], "--data", str(scene),
           "--steps", str(config["max_steps"]), "--seed", str(config["seed"]), "--output-dir", str(out),
           "--no-progress"]
process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                           env={**os.environ, "OMP_NUM_THREADS": "1"})
seen = 0
try:
    while seen < len(reference):
        logs = list(out.rglob("metrics.jsonl"))
        lines = [json.loads(x) for x in logs[0].read_text().splitlines() if x.strip()] if logs else []
        lines = [r for r in lines if "loss" in r]
        for new, old in zip(lines[seen:], reference[seen:]):
            if new["step"] != old["step"] or new["loss"] != old["loss"] or new.get("inv_s") != old.get("inv_s"):
                print(f"differ at step {new['step']}: loss {new['loss']!r} against {old['loss']!r} "
                      f"(step {old['step']}): pair new rows only with rows of this session")
                sys.exit(1)
            seen += 1
        if process.poll() is not None and seen < len(reference):
            sys.exit(f"the training ended after {seen} logged steps: {process.stderr.read()[-400:]}")
        time.sleep(2)
finally:
    if process.poll() is None:
        process.terminate()
        process.wait()
    shutil.rmtree(out, ignore_errors=True)
print(f"same bits through step {reference[-1]['step']} ({seen} logged losses): this machine repeats the reference")
