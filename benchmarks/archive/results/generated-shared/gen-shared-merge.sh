#!/bin/bash
# Gathers the real-output runs of neus, va-neus (default) and va-neus with shared_colour_weight=1 into one folder
set -e
cd "$(dirname "$0")/../../.."  # the repository root
M=outputs/gen-shared
mkdir -p $M/runs
: > $M/rows.jsonl
link() { ln -sfn "$(realpath $1)" $M/runs/$2; }
for a in aircraft_0 aircraft_1 aircraft_3; do link outputs/gen-1126/runs/$a-neus $a-neus; done
for a in aircraft_2 fox lamp; do link outputs/gen-1126b/runs/$a-neus $a-neus; link outputs/gen-1126b/runs/$a-va-neus $a-va-neus; done
link outputs/gen-1126-fix/runs/aircraft_0-va-neus aircraft_0-va-neus
link outputs/gen-1126-fix/runs/aircraft_1-va-neus aircraft_1-va-neus
link outputs/gen-1126-fix2/runs/aircraft_3-va-neus aircraft_3-va-neus
link outputs/guard/a0-shared aircraft_0-va-neus-shared
for a in aircraft_1 aircraft_3 lamp; do link outputs/gen-shared-a/runs/$a-va-neus-shared $a-va-neus-shared; done
for a in aircraft_2 fox; do link outputs/gen-shared-b/runs/$a-va-neus-shared $a-va-neus-shared; done
.venv/bin/python - <<'PY'
import json
from pathlib import Path
rows = {}
for src in ["outputs/gen-1126/rows.jsonl", "outputs/gen-1126b/rows.jsonl", "outputs/gen-1126-fix/rows.jsonl",
            "outputs/gen-1126-fix2/rows.jsonl", "outputs/gen-shared-a/rows.jsonl", "outputs/gen-shared-b/rows.jsonl"]:
    p = Path(src)
    if p.is_file():
        for line in p.read_text().splitlines():
            r = json.loads(line)
            rows[(r["input"], r["method"])] = r  # later files win: the fixed va-neus runs over the old ones
import importlib.util, sys
sys.path.insert(0, "benchmarks")
spec = importlib.util.spec_from_file_location("gen", "benchmarks/run_generated.py"); gen = importlib.util.module_from_spec(spec); spec.loader.exec_module(gen)
run = Path("outputs/guard/a0-shared")
rows[("syncdreamer/aircraft_0.png", "va-neus-shared")] = {"input": "syncdreamer/aircraft_0.png", "method": "va-neus-shared",
    "wall_seconds": 874, "threads": 1, **gen.last_metrics(run),
    **gen.rig_check(Path("../shared/data/generated/syncdreamer/aircraft_0.png"))}
with open("outputs/gen-shared/rows.jsonl", "w") as f:
    for r in rows.values():
        if r["method"] in ("neus", "va-neus", "va-neus-shared"):
            f.write(json.dumps(r) + "\n")
PY
.venv/bin/python benchmarks/run_generated.py --out $M --methods neus,va-neus,va-neus-shared --figure-only
