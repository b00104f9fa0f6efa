"""The judge: two arms (a method with its overrides) compared over GSO objects, levels and seeds, with
bootstrap intervals of the mean difference and a per-object sign count.

Each arm trains every object's 16-view scene of ``run_all_views.py`` (level 0 and 2 by default; held-out
views off the rig) once per seed. The seed is the ray sampler's (``pipeline.datamanager.seed``), the one the
earlier reseeds moved. Each run's row is kept in ``--store`` (``rows.jsonl``, keyed by arm, object, level,
views and seed), so a later variant reuses the base's rows; a stored arm run again with another method or
other overrides or under other defaults of its method is refused. Run folders (one folder per config
fingerprint, so a changed default never resumes an old run) and scenes go to ``--work``.

The report, per level, over the objects both arms have:
- each arm's mean (objects first averaged over their seeds) and its per-object seed sd (pooled over objects);
- the variant's mean difference from the base with a 95% interval: a two-level bootstrap that draws objects,
  then each arm's seeds within every drawn object. CD is compared per object as a ratio (``CD %``: the mean
  over objects of variant / base - 1) and as an absolute difference;
- the sign count: on how many objects the variant's seed mean is better.

    python benchmarks/judge.py --base neus --variant va-neus [--levels 0,2] [--seeds 42,43,44]
        [--objects alarm,bell] [--jobs 2] [--report-only] [--store benchmarks/results/judge]

An arm is ``NAME`` (a registered method) or ``NAME=METHOD KEY=VALUE ...`` (a method with config overrides,
quoted as one argument), for example ``--variant "ema=neus pipeline.model.x=1"``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import run_all_views  # a sibling script: its scenes, workers and rows

from va_plugin.errors import VAError

STORE = Path(__file__).parent / "results" / "judge"
WORK = Path("outputs/bench/judge")
VIEWS = 16
METRICS = ("psnr", "lpips", "cd", "iou")
HIGHER_IS_BETTER = {"psnr": True, "lpips": False, "cd": False, "iou": True}
BOOTSTRAP = 10_000


class Arm(NamedTuple):
    """One side of the comparison: a label, the registered method and its config overrides."""

    name: str
    method: str
    overrides: tuple[str, ...] = ()


def parse_arm(text: str) -> Arm:
    """``NAME`` or ``NAME=METHOD KEY=VALUE ...``; ``ValueError`` on an empty name or a malformed override."""
    head, *overrides = text.split()
    name, _, method = head.partition("=")
    if not name or (_ and not method):
        raise ValueError(f"arm {text!r}: expected NAME or NAME=METHOD KEY=VALUE ...")
    if any("=" not in o for o in overrides):
        raise ValueError(f"arm {text!r}: overrides are KEY=VALUE")
    return Arm(name, method or name, tuple(overrides))


def row_key(arm: str, name: str, level: int, seed: int) -> str:
    return f"{arm}/{name}-l{level}-v{VIEWS}-seed{seed}"


def load_rows(path: Path) -> dict[str, dict[str, Any]]:
    """The stored rows by key; a malformed line raises ``LookupError``."""
    rows = {}
    if not path.is_file():
        return rows
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if line.strip():
            try:
                row = json.loads(line)
                rows[row["key"]] = row
            except (json.JSONDecodeError, KeyError, TypeError) as exc:
                raise LookupError(f"{path} line {number} is not a row ({exc})") from None
    return rows


def check_arm(arm: Arm, rows: dict[str, dict[str, Any]], trains: str | None = None) -> None:
    """Refuse an arm whose stored rows were made with another method or other overrides, or (``trains``: the
    arm's :func:`fingerprint` now) under other defaults of its method."""
    for row in rows.values():
        if row.get("arm") != arm.name:
            continue
        if (row.get("method"), tuple(row.get("arm_overrides", ()))) != (arm.method, arm.overrides):
            raise LookupError(f"arm {arm.name!r} is stored as {row.get('method')} {row.get('arm_overrides', [])}; "
                              f"give the new one another name")
        if trains is not None and row.get("trains", trains) != trains:
            raise LookupError(f"arm {arm.name!r} is stored with other defaults of {arm.method} (commit "
                              f"{row.get('commit', '?')}); its new runs would not be comparable: give them "
                              "another name, or pin the old defaults with overrides")


def fingerprint(arm: Arm) -> str:
    """What an arm trains, as a short hash of its method's config with the arm's overrides (the seed, the
    data and the output folder left out): rows of one arm name under changed defaults differ here."""
    import hashlib

    from va_plugin.config import apply_override, to_dict
    from va_plugin.registry import get_method

    config = get_method(arm.method).make_config()
    for override in arm.overrides:
        apply_override(config, override)
    flat = to_dict(config)
    for key in ("output_dir", "seed", "progress", "device", "num_threads"):
        flat.pop(key, None)
    flat["pipeline"]["datamanager"].pop("seed", None)
    flat["pipeline"]["datamanager"]["dataparser"].pop("data", None)
    return hashlib.sha256(json.dumps(flat, sort_keys=True, default=str).encode()).hexdigest()[:12]


def commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return ""


def jobs_for(arm: Arm, names: list[str], levels: list[int], seeds: list[int], data_root: Path, work: Path,
             done: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """The runs ``arm`` still lacks, each with its scene built."""
    jobs, trains = [], fingerprint(arm)
    for level in levels:
        for seed in seeds:
            for name in names:
                key = row_key(arm.name, name, level, seed)
                if key in done:
                    continue
                scene = run_all_views.build(work / "scenes", data_root, name, VIEWS, level)
                jobs.append({"key": key, "object": name, "views": VIEWS, "level": level, "steps": 0, "trains": trains,
                             "variant": arm.name, "arm": arm.name, "method": arm.method,
                             "arm_overrides": list(arm.overrides),
                             "overrides": [*arm.overrides, f"pipeline.datamanager.seed={seed}"],
                             "seed": seed, "scene": str(scene), "run_dir": str(work / "runs" / trains / key),
                             "commit": commit()})
    return jobs


def per_object(rows: dict[str, dict[str, Any]], arm: str, level: int) -> dict[str, dict[str, list[float]]]:
    """``{object: {metric: [one value per seed]}}`` of an arm at a level."""
    out: dict[str, dict[str, list[float]]] = {}
    for row in rows.values():
        if row.get("arm") == arm and row["level"] == level and row["views"] == VIEWS:
            values = out.setdefault(row["object"], {m: [] for m in METRICS})
            for m in METRICS:
                values[m].append(float(row[m]))
    return out


def statistic(base: list[np.ndarray], variant: list[np.ndarray], relative: bool) -> float:
    """Mean over objects of the variant's seed mean minus the base's (``relative``: their ratio - 1)."""
    diffs = [v.mean() / b.mean() - 1 if relative else v.mean() - b.mean() for b, v in zip(base, variant)]
    return float(np.mean(diffs))


def bootstrap_interval(base: list[np.ndarray], variant: list[np.ndarray], relative: bool,
                       draws: int = BOOTSTRAP, seed: int = 0) -> tuple[float, float]:
    """95% percentile interval of :func:`statistic`: objects drawn with replacement, then each arm's seeds
    within each drawn object (afresh for an object drawn twice). ``base[i]``: object i's values, one per seed."""
    rng = np.random.default_rng(seed)
    n = len(base)
    picks = rng.integers(0, n, (draws, n))

    def resampled(arm: list[np.ndarray]) -> np.ndarray:
        """[n objects, draws, n slots]: the mean of a fresh draw of the object's seeds for every slot."""
        return np.stack([a[rng.integers(0, len(a), (draws, n, len(a)))].mean(-1) for a in arm])

    draw, slot = np.arange(draws)[:, None], np.arange(n)[None, :]
    b, v = resampled(base)[picks, draw, slot], resampled(variant)[picks, draw, slot]
    low, high = np.percentile((v / b - 1 if relative else v - b).mean(1), [2.5, 97.5])
    return float(low), float(high)


def seed_sd(values: dict[str, dict[str, list[float]]], metric: str, relative: bool) -> float | None:
    """Per-object sample sd over seeds, pooled over objects (root mean variance); ``relative``: as a
    fraction of the object's mean. None when no object has two seeds."""
    variances = []
    for per_metric in values.values():
        v = np.asarray(per_metric[metric])
        if len(v) >= 2:
            variances.append(np.var(v / v.mean() if relative else v, ddof=1))
    return float(np.sqrt(np.mean(variances))) if variances else None


def compare(rows: dict[str, dict[str, Any]], base: str, variant: str, level: int) -> dict[str, Any] | None:
    """The judge's figures for one level, or None when no object has rows of both arms."""
    a, b = per_object(rows, base, level), per_object(rows, variant, level)
    objects = sorted(set(a) & set(b))
    if not objects:
        return None
    result: dict[str, Any] = {"level": level, "objects": objects,
                              "seeds": {base: sorted({len(a[o]["cd"]) for o in objects}),
                                        variant: sorted({len(b[o]["cd"]) for o in objects})}}
    for m in METRICS:
        xs = [np.asarray(a[o][m]) for o in objects]
        ys = [np.asarray(b[o][m]) for o in objects]
        entry = {"base": float(np.mean([x.mean() for x in xs])), "variant": float(np.mean([y.mean() for y in ys])),
                 "diff": statistic(xs, ys, False), "interval": bootstrap_interval(xs, ys, False)}
        better = [(y.mean() > x.mean()) == HIGHER_IS_BETTER[m] and y.mean() != x.mean() for x, y in zip(xs, ys)]
        entry["better"] = int(sum(better))
        if m == "cd":
            entry["ratio"] = statistic(xs, ys, True)
            entry["ratio_interval"] = bootstrap_interval(xs, ys, True)
        result[m] = entry
    result["seed_sd"] = {arm: {"psnr_db": seed_sd({o: v[o] for o in objects}, "psnr", False),
                               "cd_pct": _pct(seed_sd({o: v[o] for o in objects}, "cd", True))}
                         for arm, v in ((base, a), (variant, b))}
    return result


def _pct(x: float | None) -> float | None:
    return None if x is None else 100 * x


def report(result: dict[str, Any], base: str, variant: str) -> str:
    """Markdown for one level's figures."""
    n = len(result["objects"])
    seeds = ", ".join(f"{arm} {'/'.join(map(str, s))}" for arm, s in result["seeds"].items())
    lines = [f"Level {result['level']}, {VIEWS} views, {n} objects (seeds per object: {seeds})", "",
             f"| metric | {base} | {variant} | difference [95% interval] | {variant} better on |",
             "|---|---|---|---|---|"]
    for m in METRICS:
        e = result[m]
        fmt = "{:+.4f}" if m in ("lpips", "cd", "iou") else "{:+.2f}"
        cell = f"{fmt.format(e['diff'])} [{fmt.format(e['interval'][0])}, {fmt.format(e['interval'][1])}]"
        if m == "cd":
            cell += (f"; {100 * e['ratio']:+.1f}% [{100 * e['ratio_interval'][0]:+.1f}%, "
                     f"{100 * e['ratio_interval'][1]:+.1f}%]")
        value = "{:.5f}" if m == "cd" else "{:.4f}" if m in ("lpips", "iou") else "{:.2f}"
        lines.append(f"| {m.upper()} | {value.format(e['base'])} | {value.format(e['variant'])} | {cell} | "
                     f"{e['better']}/{n} |")
    sd = result["seed_sd"]
    show = lambda x, unit: "-" if x is None else f"{x:.2f}{unit}"
    lines.append("")
    lines.append("Per-object seed sd (pooled): " + "; ".join(
        f"{arm} {show(s['psnr_db'], ' dB')}, CD {show(s['cd_pct'], '%')}" for arm, s in sd.items()))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--base", default="neus", help="the arm compared against (NAME or 'NAME=METHOD K=V ...')")
    parser.add_argument("--variant", default="va-neus", help="the arm judged")
    parser.add_argument("--levels", default="2,0", help="benchmark levels, comma-separated (run in this order)")
    parser.add_argument("--seeds", default="42,43,44", help="ray-sampler seeds, comma-separated")
    parser.add_argument("--objects", default=None, help="comma-separated GSO names (default: all)")
    parser.add_argument("--data-root", type=Path, default=Path("../shared/data/gso"))
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--store", type=Path, default=STORE, help="folder of rows.jsonl (kept in the repository)")
    parser.add_argument("--work", type=Path, default=WORK, help="folder of the scenes and run folders")
    parser.add_argument("--report-only", action="store_true", help="print the comparison of the stored rows")
    args = parser.parse_args(argv)
    try:
        base, variant = parse_arm(args.base), parse_arm(args.variant)
        levels = [int(x) for x in args.levels.split(",")]
        seeds = [int(x) for x in args.seeds.split(",")]
        if base.name == variant.name:
            raise ValueError("--base and --variant need different names")
        rows_file = args.store / "rows.jsonl"
        done = load_rows(rows_file)
        for arm in (base, variant):
            check_arm(arm, done)
        if not args.report_only:
            from va_plugin.bench.scenes import gso
            from va_plugin.config import apply_override
            from va_plugin.registry import get_method

            for arm in (base, variant):  # an unknown method or a mistyped key fails here, not in the workers
                for override in arm.overrides:
                    apply_override(get_method(arm.method).make_config(), override)
                check_arm(arm, done, fingerprint(arm))
            names = args.objects.split(",") if args.objects else gso.list_objects(args.data_root)
            args.store.mkdir(parents=True, exist_ok=True)
            jobs = [j for arm in (base, variant) for j in jobs_for(arm, names, levels, seeds, args.data_root,
                                                                     args.work, done)]
            print(f"{len(done)} rows stored, {len(jobs)} to run with {args.jobs} job(s)", file=sys.stderr)
            try:
                run_all_views.run_rows(jobs, args.jobs, rows_file, done)
            except KeyboardInterrupt:
                print("interrupted: the same command continues (running rows from their checkpoints)",
                      file=sys.stderr)
                return 130
    except (ValueError, LookupError, VAError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    texts = [report(r, base.name, variant.name) for r in (compare(done, base.name, variant.name, level)
                                                          for level in levels) if r is not None]
    if not texts:
        print(f"error: no object has rows of both {base.name!r} and {variant.name!r}", file=sys.stderr)
        return 2
    print("\n\n".join(texts))
    return 0


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    raise SystemExit(main())
