"""Start the rows of a ``run_backbone.py`` command from another run's final checkpoint, so that a
longer budget with ``schedule_steps`` continues the shorter run instead of training its first steps again.

Usage: python benchmarks/results/horizon/seed_from.py SOURCE_OUT -- RUN_BACKBONE_ARGS...

For every row the command plans, the scene is built and the row's run folder is written with its resume
marker (the row's settings fingerprint) and the newest checkpoint of the same scene's single run under
``SOURCE_OUT/runs/SCENE/``; then ``run_backbone.py RUN_BACKBONE_ARGS... --resume`` trains each row from
that step on. With ``schedule_steps`` equal to the source's budget the result is the uninterrupted longer
run (resume is bitwise, tests/engine/test_trainer.py), provided the source ran the same code and options.
"""
import json
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from run_backbone import EXPERIMENT  # noqa: E402

from va_plugin.bench.cli import ExperimentRun, build_parser  # noqa: E402
from va_plugin.bench.rows import ROW_FILE  # noqa: E402
from va_plugin.engine.trainer import list_checkpoints  # noqa: E402

source = Path(sys.argv[1])
args = build_parser(EXPERIMENT).parse_args(sys.argv[3:])
run = ExperimentRun(EXPERIMENT, args, "seed_from")
for index, row in enumerate(run.rows):
    task = run.prepare(index, row)
    if task is None:
        continue
    scene = row.key.split("/")[0]
    candidates = sorted((source / "runs" / scene).glob("*/*/checkpoints"))
    if len(candidates) != 1:
        sys.exit(f"{scene}: expected one source run under {source / 'runs' / scene}, found {len(candidates)}")
    checkpoint = list_checkpoints(candidates[0].parent)[-1]
    run_dir = Path(task.config.output_dir)
    shutil.rmtree(run_dir, ignore_errors=True)
    (run_dir / "checkpoints").mkdir(parents=True)
    shutil.copy2(checkpoint, run_dir / "checkpoints" / checkpoint.name)
    (run_dir / ROW_FILE).write_text(json.dumps({"key": row.key, "fingerprint": task.fingerprint}))
    print(f"{row.key}: from {checkpoint}")
