"""Each generator format, end to end on data it did not write: GSO objects (or procedural ones) rendered on
each generator's rig, written in its layout (file names, sizes, background, tile order), reconstructed by
``va-recon``'s path (``va_plugin.reconstruct`` with ``--data-format`` the rig's name) and scored (CD, IoU,
F-score against the true mesh brought into the training frame, unit-box protocol).

    python benchmarks/run_formats.py --sources gso:alarm,gso:backpack --data-root ../shared/data/gso \\
        --formats hunyuan3d-std,mvadapter,sv3d,era3d,crm,four-view-grid --levels 0,2 [--steps N] \\
        [--tile N] [--out outputs/formats] [--resume]

Writes ``OUT/scenes/<format>/NAME/`` (the generator-layout input, mesh.ply, scene.json), ``OUT/runs/<format>/NAME/``
(the run; NAME is ``<object>-L<level>``, then ``-s<seed>`` and ``-e<elevation>`` where not the defaults) and
``OUT/formats.json`` / ``OUT/formats.md`` (one row per format, object and level, and the mean per format and
level). Default: ``neus`` with its default steps,
every view of each rig at its native size. ``--resume`` skips rows already in formats.json (same format,
source, level, seed, overrides and elevation).

    python benchmarks/run_formats.py --report OUT_A/formats.json [OUT_B/formats.json ...] [--reference syncdreamer@4]

prints each format beside the reference format on the objects both ran: mean CD and IoU, the mean
per-object CD ratio with a 95% bootstrap interval over objects, and the objects with IoU below 0.5.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from judge import bootstrap_interval, statistic  # a sibling script: the judge's paired figures

from va_plugin.api import reconstruct
from va_plugin.bench.scenes.generator_scene import build_generator_scene, score_generator_run
from va_plugin.config import apply_override
from va_plugin.data.rigfile import builtin_rigs
from va_plugin.engine.options import check_views
from va_plugin.errors import ConfigError, VAError
from va_plugin.registry import get_method

REPO = Path(__file__).resolve().parents[1]
DEFAULT_FORMATS = "hunyuan3d-std,hunyuan3d-lite,mvadapter,sv3d,era3d,crm,wonder3dpp-ortho,four-view-grid"
DEFAULT_SEED = 42  # rows written before rows recorded their seed ran with it


def split_format(fmt: str) -> tuple[str, int | str]:
    """``syncdreamer@4`` -> (``syncdreamer``, 4): a rig trained on that many of its views; ``crm`` -> all."""
    rig, at, views = fmt.partition("@")
    if at and not views.isdigit():
        raise ValueError(f"format {fmt}: RIG@N needs N a whole number of views, e.g. syncdreamer@4")
    try:
        return rig, check_views(int(views)) if at else "all"
    except ConfigError as error:  # va-recon's own rule for a view count
        raise ValueError(f"format {fmt}: {error}") from None


def run_name(source: str, level: int, args: argparse.Namespace) -> str:
    """The scene and run folder of one row: object and level, then the seed and elevation where they are not
    the defaults (the scene depends on both, so rows of another seed or elevation never reuse it)."""
    return (f"{source.split(':', 1)[1]}-L{level}" + (f"-s{args.seed}" if args.seed != DEFAULT_SEED else "")
            + (f"-e{args.elevation:g}" if args.elevation is not None else ""))


def run_row(fmt: str, source: str, level: int, args: argparse.Namespace) -> dict:
    name = run_name(source, level, args)
    rig, views = split_format(fmt)
    scene_dir = args.out / "scenes" / rig / name
    started = time.perf_counter()
    if not (scene_dir / "scene.json").is_file():
        spec = builtin_rigs()[rig].with_options(elevation_deg=args.elevation)
        build_generator_scene(scene_dir, spec, source, level=level, seed=args.seed, tile=args.tile,
                              data_root=args.data_root)
    data = json.loads((scene_dir / "scene.json").read_text())["input"]
    built = time.perf_counter() - started
    result = reconstruct(scene_dir / data, args.out / "runs" / fmt.replace("@", "-") / name, method=args.method,
                         data_format=rig, views=views, steps=args.steps, texture=False, turntable_frames=0,
                         seed=args.seed, overwrite=True, device=args.device, overrides=list(args.overrides),
                         elevation=args.elevation)
    meta = result.config.pipeline.datamanager.dataparser.setup().get_outputs("train").metadata
    scores = score_generator_run(result.mesh, scene_dir, meta["rig_to_training"])
    return {"format": fmt, "source": source, "level": level, "seed": args.seed, "views": result.views,
            "steps": result.steps,
            "cd": scores["cd"], "iou": scores["iou"], "fscore": scores["fscore"],
            "silhouette_iou_mean": sum(meta["silhouette_iou"]) / len(meta["silhouette_iou"]),
            "train_seconds": result.train_seconds, "build_seconds": round(built, 1),
            "tile": json.loads((scene_dir / "scene.json").read_text())["tile"],
            **({"overrides": list(args.overrides)} if args.overrides else {}),
            **({"elevation": args.elevation} if args.elevation is not None else {})}


def write_report(rows: list[dict], out: Path, command: str) -> None:
    (out / "formats.json").write_text(json.dumps(rows, indent=2))
    lines = [f"`{command}`", "", "| format | source | level | views | tile | steps | CD | IoU | F-score | hull IoU | "
             "train s |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    lines.extend(f"| {r['format']} | {r['source']} | {r['level']} | {r['views']} | {r['tile']} | {r['steps']} | "
                 f"{r['cd']:.4f} | {r['iou']:.3f} | {r['fscore']:.3f} | {r['silhouette_iou_mean']:.3f} | "
                 f"{r['train_seconds']:.0f} |" for r in rows)
    lines += ["", "| format | level | objects | mean CD | mean IoU | IoU < 0.5 |", "|---|---|---|---|---|---|"]
    for fmt in dict.fromkeys(r["format"] for r in rows):
        for level in sorted({r["level"] for r in rows if r["format"] == fmt}):
            group = [r for r in rows if r["format"] == fmt and r["level"] == level]
            lines.append(f"| {fmt} | {level} | {len(group)} | {sum(r['cd'] for r in group) / len(group):.4f} | "
                         f"{sum(r['iou'] for r in group) / len(group):.3f} | "
                         f"{sum(r['iou'] < 0.5 for r in group)} |")
    (out / "formats.md").write_text("\n".join(lines) + "\n")


def compare_formats(rows: list[dict], reference: str, level: int) -> list[str]:
    """Markdown rows: each format at ``level`` against ``reference`` on the objects both have; an object with
    rows of several seeds counts with its mean over them (the judge's interval draws seeds within objects)."""
    by_format: dict[str, dict[str, list[dict]]] = {}
    for r in rows:
        if r["level"] == level:
            label = r["format"] + (f" (elevation {r['elevation']:g})" if r.get("elevation") is not None else "")
            by_format.setdefault(label, {}).setdefault(r["source"], []).append(r)
    ref = by_format.get(reference, {})
    lines = [f"Level {level}; reference `{reference}`", "",
             "| format | views x px | objects | seeds | mean CD | reference CD | CD per object vs reference [95%] | "
             "lower CD on | mean IoU | reference IoU | IoU < 0.5 (reference's) |", "|---" * 11 + "|"]

    def values(runs: list[dict], key: str) -> np.ndarray:
        return np.array([r[key] for r in runs])

    for fmt, got in by_format.items():
        objects = sorted(set(got) & set(ref)) if fmt != reference else sorted(got)
        if not objects:
            continue
        cd = [values(got[o], "cd") for o in objects]
        ref_cd = [values(ref[o], "cd") for o in objects] if ref else cd
        ratio = statistic(ref_cd, cd, relative=True)
        low, high = bootstrap_interval(ref_cd, cd, relative=True)
        lower = sum(c.mean() < b.mean() for c, b in zip(cd, ref_cd))
        iou = [values(got[o], "iou").mean() for o in objects]
        ref_iou = [values(ref[o], "iou").mean() for o in objects] if ref else [float("nan")]
        small = [o.split(":", 1)[1] for o, v in zip(objects, iou) if v < 0.5]
        ref_small = [o.split(":", 1)[1] for o, v in zip(objects, ref_iou) if ref and v < 0.5]
        seeds = sorted({r.get("seed", DEFAULT_SEED) for o in objects for r in got[o]})
        first = got[objects[0]][0]
        lines.append(f"| {fmt} | {first['views']} x {first['tile']} | {len(objects)} | "
                     f"{', '.join(map(str, seeds))} | {np.mean([c.mean() for c in cd]):.4f} | "
                     f"{np.mean([b.mean() for b in ref_cd]):.4f} | "
                     f"{100 * ratio:+.1f}% [{100 * low:+.1f}%, {100 * high:+.1f}%] | {lower}/{len(objects)} | "
                     f"{np.mean(iou):.3f} | {np.mean(ref_iou):.3f} | "
                     f"{', '.join(small) or '-'} ({', '.join(ref_small) or '-'}) |")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--formats", default=DEFAULT_FORMATS,
                        help=f"built-in rigs, RIG@N for N of its views (default {DEFAULT_FORMATS})")
    parser.add_argument("--sources", default="procedural:mug", help="gso:NAME (with --data-root) or procedural:NAME")
    parser.add_argument("--data-root", type=Path, default=REPO.parent / "shared" / "data" / "gso")
    parser.add_argument("--levels", default="0,2")
    parser.add_argument("--method", default="neus")
    parser.add_argument("--steps", type=int, default=None, help="training steps (default: the method's)")
    parser.add_argument("--tile", type=int, default=None, help="view size (default: each generator's own)")
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED)
    parser.add_argument("--device", default="auto")
    parser.add_argument("--out", type=Path, default=Path("outputs") / "formats")
    parser.add_argument("--resume", action="store_true")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="PATH=VALUE",
                        help="a config override for every run, as va-recon's --set; the rows record it")
    parser.add_argument("--elevation", type=float, default=None, metavar="DEG",
                        help="every view's elevation, written and read so (rigs whose views share one); "
                             "the rows record it")
    parser.add_argument("--report", nargs="+", type=Path, metavar="FORMATS_JSON",
                        help="print the comparison of these formats.json files with --reference, run nothing")
    parser.add_argument("--reference", default="syncdreamer@4", help="the format --report compares with")
    args = parser.parse_args(argv)
    if args.report:
        rows = [row for path in args.report for row in json.loads(path.read_text())]
        for level in sorted({r["level"] for r in rows}):
            print("\n".join(compare_formats(rows, args.reference, level)) + "\n")
        return 0
    formats = [f.strip() for f in args.formats.split(",") if f.strip()]
    try:
        unknown = [f for f in formats if split_format(f)[0] not in builtin_rigs()]
    except ValueError as error:
        parser.error(str(error))
    if unknown:
        parser.error(f"unknown format(s) {', '.join(unknown)}; built-in rigs: {', '.join(builtin_rigs())}")
    try:
        for fmt in formats:
            builtin_rigs()[split_format(fmt)[0]].with_options(elevation_deg=args.elevation)
    except VAError as error:
        parser.error(str(error))
    for override in args.overrides:  # a mistyped key fails here, before any scene is built
        try:
            apply_override(get_method(args.method).make_config(), override)
        except VAError as error:
            parser.error(str(error))
    args.out.mkdir(parents=True, exist_ok=True)
    done = json.loads((args.out / "formats.json").read_text()) if args.resume and \
        (args.out / "formats.json").is_file() else []
    rows = list(done)
    command = "python benchmarks/run_formats.py " + " ".join(argv if argv is not None else sys.argv[1:])
    for fmt in formats:
        for source in (s.strip() for s in args.sources.split(",") if s.strip()):
            for level in (int(v) for v in args.levels.split(",")):
                if any((r["format"], r["source"], r["level"], r.get("seed", DEFAULT_SEED), r.get("overrides", []),
                        r.get("elevation")) == (fmt, source, level, args.seed, args.overrides, args.elevation)
                       for r in done):
                    continue
                row = run_row(fmt, source, level, args)
                print(f"{fmt} {source} level {level}: CD {row['cd']:.4f} IoU {row['iou']:.3f} "
                      f"({row['train_seconds']:.0f} s)", flush=True)
                rows.append(row)
                write_report(rows, args.out, command)
    return 0


if __name__ == "__main__":
    sys.exit(main())
