"""``va-batch INPUTS --method METHOD --out OUT``: reconstruct every object of a folder, one job per object.

Exit status: 0 when every object finished, 1 when any failed, 2 for a bad command, 130 on Ctrl-C.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import asdict
from typing import Any

from tqdm import tqdm

from va_plugin.api import build_config
from va_plugin.batch.engines import ENGINES, import_ray, run_local, run_ray
from va_plugin.batch.inputs import find_objects
from va_plugin.batch.job import Evaluation, ObjectJob
from va_plugin.batch.manifest import SETTINGS_FILE, Manifest
from va_plugin.batch.summary import contact_sheet, write_summary
from va_plugin.cli.common import (
    EXIT_INTERRUPTED,
    ArgumentParser,
    add_export_options,
    add_quiet_option,
    export_config,
    friendly_errors,
    path_argument,
)
from va_plugin.cli.train import add_object_options
from va_plugin.engine.run_folder import check_writable_folder
from va_plugin.errors import ConfigError
from va_plugin.export.config import ExportConfig
from va_plugin.utils.progress import progress_bar

EXIT_SOME_FAILED = 1


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(
        prog="va-batch", description="Reconstruct every object of a folder: train, export the mesh and evaluate "
        "against ground truth where the object has it, one job per object.",
        epilog="Writes OUT/runs/NAME (one va-train run folder per object, with mesh.ply, mesh.glb and mesh.obj "
               "(textured, +Y up), "
               "thumbnail.png, eval.json and batch.log), OUT/manifest.jsonl, OUT/summary.csv, OUT/summary.md and "
               "OUT/contact_sheet.png. "
               "The options after --no-progress are va-train's and hold for every object.")
    parser.add_argument("inputs", type=path_argument,
                        help="a folder of generator outputs and/or scene folders, or a text file listing them (one "
                             "path a line)")
    parser.add_argument("--method", required=True, help="a registered method (va-train --help lists them)")
    parser.add_argument("--out", type=path_argument, required=True, help="batch folder")
    parser.add_argument("--engine", choices=ENGINES, default="local",
                        help="local: worker processes on this machine (default); ray: one Ray task per object")
    parser.add_argument("--workers", type=int, default=None,
                        help="objects at once (local engine, or the local Ray instance); "
                             "default: CPU cores / --threads")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (Ray: CPUs) per object (default 1)")
    parser.add_argument("--ray-address", default=None, help="join this Ray cluster ('auto': the one this machine "
                        "belongs to); default: start a local Ray instance for the batch")
    parser.add_argument("--gpus-per-job", type=float, default=0.0, help="Ray: GPUs per object (e.g. 1 or 0.5)")
    parser.add_argument("--resume", action="store_true", help="continue a batch folder: skip the objects its "
                        "manifest holds, continue interrupted ones from their checkpoints")
    parser.add_argument("--retry-failed", action="store_true", help="with --resume: run failed objects again")
    parser.add_argument("--overwrite", action="store_true",
                        help="write the batch into --out even when it holds other files")
    parser.add_argument("--eval-image-scale", type=float, default=1.0, help="held-out views rendered at this scale")
    parser.add_argument("--eval-max-views", type=int, default=None, help="evaluate at most this many held-out views")
    parser.add_argument("--eval-samples", type=int, default=100_000,
                        help="surface samples per mesh for the Chamfer distance and F-score")
    add_export_options(parser)
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_quiet_option(parser)
    add_object_options(parser)
    return parser


def object_option_names() -> list[str]:
    """The argparse names of va-train's per-object options, which every job passes on to va-train."""
    probe = argparse.ArgumentParser(add_help=False)
    add_object_options(probe)
    return [action.dest for action in probe._actions]


def check_options(args: argparse.Namespace) -> None:
    """Refuse a bad command before any job starts (one line each)."""
    build_config(args.method, preset=args.preset, overrides=args.overrides)
    if args.threads < 1 or (args.workers is not None and args.workers < 1):
        raise ConfigError("--workers and --threads must be at least 1")
    if args.steps is not None and args.steps < 1:
        raise ConfigError(f"--steps must be at least 1, got {args.steps}")
    if args.eval_image_scale <= 0 or args.eval_samples < 1:
        raise ConfigError("--eval-image-scale must be positive and --eval-samples at least 1")
    if args.engine != "ray" and (args.ray_address or args.gpus_per_job):
        raise ConfigError("--ray-address and --gpus-per-job need --engine ray")
    if args.retry_failed and not args.resume:
        raise ConfigError("--retry-failed goes with --resume")
    export_config(args)
    check_writable_folder(args.out, flag="--out", inputs=[args.inputs], overwrite=args.overwrite,
                          marker=SETTINGS_FILE)
    if args.engine == "ray":
        import_ray()


def _result_line(record: dict[str, Any]) -> str:
    if record["status"] != "ok":
        return f"failed {record['name']}: {record.get('error', '')}"
    metrics = ", ".join(f"{k} {record[k]:.4g}" for k in ("cd", "iou", "psnr", "lpips") if record.get(k) is not None)
    return f"ok     {record['name']} ({record['seconds']:.1f} s{'; ' + metrics if metrics else ''})"


@friendly_errors
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    check_options(args)
    objects = find_objects(args.inputs)
    out = args.out.expanduser().resolve()
    workers = args.workers or max(1, (os.cpu_count() or 1) // args.threads)
    options = {name: getattr(args, name) for name in object_option_names()}
    if options.get("fov") is None:  # batches started before --fov existed resume
        options.pop("fov", None)
    evaluation = Evaluation(args.eval_image_scale, args.eval_max_views, args.eval_samples)
    export = export_config(args)
    settings = {"method": args.method, "options": options,
                "evaluation": {"mesh_resolution": export.mesh_resolution, **asdict(evaluation)},
                "texture_size": export.texture_size if export.texture else 0, "fusion": export.fusion}
    # the mesh-file settings only when not the defaults, so batches started before they existed resume
    defaults = ExportConfig()
    settings.update({k: v for k, v, default in (("faces", export.faces, defaults.faces),
                                                ("frame", export.frame, defaults.frame)) if v != default})
    manifest = Manifest(out, settings, args.resume)
    jobs = [ObjectJob(o.name, o.path, out / "runs" / o.name, args.method, options, args.threads, evaluation, export)
            for o in objects if not manifest.finished(o.name, args.retry_failed)]
    names = [o.name for o in objects]

    def ordered() -> list[dict[str, Any]]:
        return [manifest.records[n] for n in names if n in manifest.records]

    engine = (f"Ray ({args.ray_address or 'local instance'}), {args.threads} CPU(s) a job" if args.engine == "ray"
              else f"{min(workers, max(1, len(jobs)))} worker(s) x {args.threads} thread(s)")
    if not args.quiet:
        print(f"va-batch: {len(objects)} objects, {len(objects) - len(jobs)} already done, {len(jobs)} to run on "
              f"{engine}; {args.method} -> {out}", file=sys.stderr)
    bar = progress_bar(total=len(objects), initial=len(objects) - len(jobs), unit="object", desc="va-batch",
                       disable=args.no_progress or args.quiet, dynamic_ncols=True)

    def on_done(record: dict[str, Any]) -> None:
        manifest.add(record)
        write_summary(out, ordered())
        bar.update(1)
        bar.set_postfix(failed=sum(r["status"] != "ok" for r in manifest.records.values()))
        if not args.quiet:
            tqdm.write(_result_line(record), file=sys.stderr)

    started = time.perf_counter()
    try:
        if args.engine == "ray":
            run_ray(jobs, on_done, args.ray_address, workers, args.threads, args.gpus_per_job)
        else:
            run_local(jobs, workers, on_done)
    except KeyboardInterrupt:
        bar.close()
        print(f"interrupted: {len(ordered())} of {len(objects)} objects done; continue with --resume",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    bar.close()
    records = ordered()
    write_summary(out, records)
    sheet = contact_sheet(out, records)
    failed = [r for r in records if r["status"] != "ok"]
    print(f"{len(records) - len(failed)} ok, {len(failed)} failed; {time.perf_counter() - started:.1f} s for "
          f"{len(jobs)} job(s); {out / 'summary.md'}" + (f", {sheet}" if sheet else ""))
    return EXIT_SOME_FAILED if failed else 0


if __name__ == "__main__":
    sys.exit(main())
