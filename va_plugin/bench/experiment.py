"""The harness every experiment script in ``benchmarks/`` runs on: an :class:`Experiment` says how to plan
its rows and write its report; :func:`run_experiment` builds the scenes, trains and scores the rows (in this
process or in workers), keeps each finished row (``OUT/rows.jsonl``, resumable), shows progress and
rewrites the reports after every row. The command line over it (the shared flags, ``error: ...`` and exit
2 on bad input) is :mod:`va_plugin.cli.bench`; ``args`` below are its parsed flags.
"""

from __future__ import annotations

import dataclasses
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from va_plugin.bench.catalog import ensure_scene, expand_scene_names
from va_plugin.bench.parallel import RowTask, run_in_processes
from va_plugin.bench.presets import BACKBONES, BenchPreset, get_preset
from va_plugin.bench.report import fmt, machine_info
from va_plugin.bench.rows import RowSpec, fingerprint, row_config, run_row, run_steps, scene_of
from va_plugin.bench.store import ResultStore
from va_plugin.errors import ConfigError
from va_plugin.utils.interrupts import EXIT_INTERRUPTED


@dataclass
class Experiment:
    name: str  # output files OUT/<name>.md|.csv|.json; default folder outputs/bench/<name>-<preset>
    title: str
    description: str
    # (preset, the parsed flags of cli/bench.py, scene sources) -> the rows, in the order they run
    plan: Callable[[BenchPreset, Any, list[str]], list[RowSpec]]
    # (finished rows in plan order, out folder, meta) -> files written (the Markdown report first)
    report: Callable[[list[dict[str, Any]], Path, dict[str, Any]], list[Path]]
    add_arguments: Callable[[Any], None] | None = None  # the experiment's own flags, on the command line's parser
    axis_scenes: bool = False  # default scenes: the preset's ``axis_scenes``
    fixed: Sequence[str] = ()  # scene settings the experiment varies itself ("level", "views"): no flags
    default_backbones: str = "neus,ngp"


def comma_list(text: str, kind=str) -> list[Any]:
    try:
        return [kind(part.strip()) for part in text.split(",") if part.strip()]
    except ValueError:
        raise ConfigError(f"expected a comma-separated list of {kind.__name__}, got {text!r}") from None


def preset_from_args(args: Any) -> BenchPreset:
    """The named preset with the flags that change it applied."""
    preset = get_preset(args.preset)
    changes: dict[str, Any] = {}
    if args.scenes is not None:
        names = tuple(comma_list(args.scenes))
        changes.update(scenes=names, axis_scenes=names)
    if args.level is not None:
        changes["level"] = args.level
    if args.views is not None:
        changes["views"] = args.views
    if args.steps is not None:
        if args.steps < 1:
            raise ConfigError(f"--steps must be at least 1, got {args.steps}")
        changes["steps"] = dict.fromkeys(BACKBONES, args.steps)
    return dataclasses.replace(preset, **changes)


def backbones_from_args(args: Any) -> list[str]:
    backbones = comma_list(args.backbones)
    unknown = [b for b in backbones if b not in BACKBONES]
    if unknown or not backbones:
        raise ConfigError(f"--backbones takes {', '.join(BACKBONES)}; got {args.backbones!r}")
    return backbones


def adaptive_overrides(args: Any) -> tuple:
    """``--force-adaptive`` and ``--adaptive-set`` as overrides of the view-adaptive rows."""
    forced = ("pipeline.model.field.skip_consistent_scenes=false",) if args.force_adaptive else ()
    extra = tuple(args.adaptive_set)
    bad = [a for a in extra if "=" not in a or not a.split("=", 1)[0].strip()]
    if bad:
        raise ConfigError(f"--adaptive-set takes PATH=VALUE, got {bad[0]!r}")
    return forced + extra


def paired_rows(experiment: str, scene, args: Any) -> list[RowSpec]:
    """Per backbone, the original row then the adaptive row on one scene (adjacent, so that both see about
    the same load on a shared machine)."""
    rows = []
    for backbone in backbones_from_args(args):
        rows.append(RowSpec(experiment, scene, backbone, adaptive=False))
        rows.append(RowSpec(experiment, scene, backbone, adaptive=True, overrides=adaptive_overrides(args)))
    return rows


def paired_axis_rows(experiment: str, preset, args: Any, sources: Sequence[str],
                     values: Sequence[int], scene_key: str) -> list[RowSpec]:
    """:func:`paired_rows` on every source at every value of one scene setting (``scene_key``: "level",
    "views"), in the order source, value, backbone."""
    return [row for source in sources for value in values
            for row in paired_rows(experiment, scene_of(source, preset, args.seed, **{scene_key: value}), args)]


def axis_values(text: str | None, default: Sequence[int]) -> list[int]:
    """A comma-separated list of integers from a flag, or the preset's values."""
    return comma_list(text, int) if text else list(default)


def duration(seconds: float) -> str:
    seconds = round(seconds)
    hours, rest = divmod(seconds, 3600)
    return f"{hours}h{rest // 60:02d}m" if hours else f"{rest // 60}m{rest % 60:02d}s"


class Progress:
    """Elapsed time and an estimate of the rest: seconds per step so far times the steps left, divided by
    the rows that run at once."""

    def __init__(self, budgets: Sequence[int], jobs: int = 1) -> None:
        self.started = time.perf_counter()
        self.budgets = list(budgets)
        self.jobs = jobs
        self.remaining = set(range(len(budgets)))
        self.running: dict[int, float] = {}  # rows under way -> when they started
        self.steps_done = 0
        self.seconds_spent = 0.0

    def elapsed(self) -> float:
        return time.perf_counter() - self.started

    def start(self, index: int) -> None:
        self.running[index] = time.perf_counter()

    def skip(self, index: int) -> None:
        self.remaining.discard(index)
        self.running.pop(index, None)

    def finish(self, index: int) -> float:
        """Count the row as done; its seconds since :meth:`start`."""
        seconds = time.perf_counter() - self.running.pop(index)
        self.remaining.discard(index)
        self.steps_done += self.budgets[index]
        self.seconds_spent += seconds
        return seconds

    def estimate(self) -> str:
        if not self.steps_done:
            return "no estimate yet"
        per_step, now = self.seconds_spent / self.steps_done, time.perf_counter()
        work = sum(max(0.0, self.budgets[i] * per_step - (now - self.running.get(i, now)))
                   for i in self.remaining)
        return f"about {duration(work / max(1, min(self.jobs, len(self.remaining))))} left"

    def prefix(self, index: int) -> str:
        return f"[row {index + 1}/{len(self.budgets)} | {duration(self.elapsed())} elapsed, {self.estimate()}]"


def describe(result: dict[str, Any]) -> str:
    parts = [f"PSNR {fmt(result.get('psnr'), 'psnr')}", f"CD {fmt(result.get('cd'), 'cd')}",
             f"IoU {fmt(result.get('iou'), 'iou')}", f"train {result['train_seconds']:.0f} s"]
    if result["adaptive"]:
        parts.append("adaptive phases ran" if result.get("adaptive_ran") else "adaptive phases skipped")
    if result.get("error"):
        parts.append(f"note: {result['error']}")
    return ", ".join(parts)


def _settings(preset: BenchPreset, rows: list[RowSpec]) -> str:
    scenes = ", ".join(dict.fromkeys(r.scene.name for r in rows))
    steps = ", ".join(f"{b} {run_steps(r, preset)}" for b, r in
                      {r.backbone: r for r in rows}.items())
    levels = sorted({r.scene.level for r in rows})
    views = sorted({r.scene.views for r in rows})
    return (f"scenes: {scenes}; level {', '.join(map(str, levels))}; {', '.join(map(str, views))} input views at "
            f"{preset.resolution} px; steps per run: {steps} (method preset: {preset.method_preset or 'default'}); "
            f"{preset.curve_points} checkpoints evaluated along each run")


def jobs_and_threads(args: Any) -> tuple:
    """(rows at once, torch threads of each row) from ``--jobs`` and ``--threads`` (threads 0: torch's
    default for one row at a time, the CPU count shared out between the rows otherwise)."""
    if args.jobs < 1:
        raise ConfigError(f"--jobs must be at least 1, got {args.jobs}")
    if args.threads > 0:
        return args.jobs, args.threads
    return args.jobs, (0 if args.jobs == 1 else max(1, (os.cpu_count() or 1) // args.jobs))


class ExperimentRun:
    """One run of an experiment: its rows, their store, the progress and the reports. Rows run in this
    process or ``jobs`` at a time in workers; each goes through :meth:`prepare` (scene, config,
    fingerprint; or the stored row), :meth:`start` and :meth:`finish`."""

    def __init__(self, experiment: Experiment, args: Any, command: str) -> None:
        self.experiment, self.args = experiment, args
        self.preset = preset = preset_from_args(args)
        self.jobs, self.threads = jobs_and_threads(args)
        out = args.out if args.out is not None else Path("outputs") / "bench" / f"{experiment.name}-{preset.name}"
        self.out = out.resolve()
        sources = expand_scene_names(preset.axis_scenes if experiment.axis_scenes else preset.scenes, args.data_root)
        if not sources:
            raise ConfigError("no scenes to run")
        self.rows = experiment.plan(preset, args, sources)
        self.store = ResultStore(self.out, args.resume)
        self.progress = Progress([run_steps(row, preset) for row in self.rows], self.jobs)
        self.meta: dict[str, Any] = {
            "experiment": experiment.name, "title": experiment.title, "command": command,
            "date": datetime.now().strftime("%Y-%m-%d %H:%M"), "preset": preset.name,
            "preset_description": preset.description, "settings": _settings(preset, self.rows),
            "machine": machine_info(), "rows_planned": len(self.rows), "jobs": self.jobs}
        self.meta["machine"]["load_average_start"] = self.meta["machine"].pop("load_average", None)
        if self.jobs > 1:
            self.meta["machine"]["torch_threads"] = self.threads
        self.results: dict[str, dict[str, Any]] = {}  # finished rows by key (run now or taken from the store)
        self.skipped = 0  # rows taken from the store

    def write_reports(self) -> list[Path]:
        done = [self.results[r.key] for r in self.rows if r.key in self.results]
        self.meta.update(rows_done=len(done), rows_run=len(done) - self.skipped,
                         wall=duration(self.progress.elapsed()))
        self.meta["machine"]["load_average_end"] = machine_info().get("load_average")
        return self.experiment.report(done, self.out, self.meta)

    def prepare(self, index: int, row: RowSpec) -> RowTask | None:
        """The row's scene (built when missing), config and fingerprint; None when it finished earlier."""
        out, progress = self.out, self.progress
        scene_dir = out / "scenes" / row.scene.folder_name
        if not (scene_dir / "scene.json").is_file():
            print(f"{progress.prefix(index)} building scene {row.scene.name} (level {row.scene.level}, "
                  f"{row.scene.views} views, {row.scene.resolution} px)", flush=True)
        scene_dir = ensure_scene(row.scene, out / "scenes", self.args.data_root)
        config = row_config(row, self.preset, scene_dir, out / "runs" / row.key, self.args.seed, self.args.device)
        row_fingerprint = fingerprint(config, self.preset.evaluation, out)
        stored = self.store.finished(row.key, row_fingerprint)
        if stored is None:
            return RowTask(index, row, config, scene_dir, self.preset.evaluation, row_fingerprint)
        self.results[row.key] = stored
        progress.skip(index)
        self.skipped += 1
        print(f"{progress.prefix(index)} {row.scene.name}: {row.label}: finished earlier, skipped", flush=True)
        return None

    def start(self, task: RowTask) -> None:
        if task.index not in self.progress.running:  # the sequential path starts the clock before the scene
            self.progress.start(task.index)
        row = task.row
        print(f"{self.progress.prefix(task.index)} {row.scene.name}: {row.label} ({row.method}, "
              f"{task.config.max_steps} steps)", flush=True)

    def finish(self, task: RowTask, result: dict[str, Any]) -> None:
        self.store.add(result)
        self.results[task.row.key] = result
        seconds = self.progress.finish(task.index)
        where = "    " if self.jobs == 1 else \
            f"{self.progress.prefix(task.index)} {task.row.scene.name}: {task.row.label}: "
        print(f"{where}done in {duration(seconds)}: {describe(result)}", flush=True)
        self.write_reports()

    def failed(self, task: RowTask) -> None:
        self.progress.running.pop(task.index)
        print(f"{self.progress.prefix(task.index)} {task.row.scene.name}: {task.row.label}: failed in its worker "
              "process; stopping the other rows", flush=True)

    def interrupted(self, in_flight: str) -> int:
        if self.results:
            self.write_reports()
        print(f"\ninterrupted in {in_flight}; finished rows are kept in {self.store.path}. "
              "Rerun the same command with --resume to continue.", file=sys.stderr)
        return EXIT_INTERRUPTED

    def run_sequentially(self) -> int | None:
        """Every row in this process; the exit status when interrupted, else None."""
        for index, row in enumerate(self.rows):
            self.progress.start(index)
            task = self.prepare(index, row)
            if task is None:
                continue
            self.start(task)
            task.config.progress = sys.stderr.isatty()
            try:
                result = run_row(row, task.config, task.scene_dir, self.preset.evaluation, task.fingerprint)
            except KeyboardInterrupt:
                return self.interrupted(f"row {index + 1} ({row.key})")
            self.finish(task, result)
        return None

    def run_in_workers(self) -> int | None:
        """The rows ``jobs`` at a time in worker processes; the exit status when interrupted, else None."""
        tasks = [task for task in (self.prepare(index, row) for index, row in enumerate(self.rows))
                 if task is not None]
        for task in tasks:
            task.config.progress = False  # bars of rows running at once would overwrite each other
        try:
            run_in_processes(tasks, self.jobs, self.threads, self.start, self.finish, self.failed)
        except KeyboardInterrupt:
            return self.interrupted("row(s) " + ", ".join(f"{i + 1} ({self.rows[i].key})"
                                                          for i in sorted(self.progress.running)))
        return None


def run_experiment(experiment: Experiment, args: Any, command: str) -> int:
    run = ExperimentRun(experiment, args, command)
    if run.jobs == 1 and run.threads > 0:
        import torch

        torch.set_num_threads(run.threads)
    at_once = f"; {run.jobs} rows at a time, {run.threads} torch thread{'' if run.threads == 1 else 's'} each" \
        if run.jobs > 1 else ""
    print(f"{experiment.title}: {len(run.rows)} rows, preset {run.preset.name}, results in {run.out}{at_once}",
          flush=True)
    status = run.run_sequentially() if run.jobs == 1 else run.run_in_workers()
    if status is not None:
        return status
    written = run.write_reports()
    print(f"\n{experiment.title}: {len(run.rows) - run.skipped} rows run, {run.skipped} skipped as finished, "
          f"in {duration(run.progress.elapsed())}")
    if written:
        print(Path(written[0]).read_text())
        print("files: " + ", ".join(str(p) for p in written))
    return 0
