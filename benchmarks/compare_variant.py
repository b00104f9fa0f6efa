"""A screened variant of the 16-view GSO rows against the default's seeds, object by object.

Reads ``benchmarks/results/all-views/rows-l2.jsonl`` (or ``--rows``) and prints a markdown table: per object
the variant against the mean of the default's seeds (PSNR, LPIPS, CD), against the first seed alone, and how
far the seeds lie apart (their pairs' mean difference). Objects where the variant loses more than twice the
reseed spread in PSNR or CD (the per-object rule of the speed screens) are marked, the spread being

- ``pooled`` (the default): the seeds' difference averaged over every object that has all the seeds;
- ``own``: that object's own seed difference. A third seed of the default itself crosses this rule on one
  object or more of ten about nine times in ten (an object's two seeds can lie close by chance).

The last lines hold the means and the rule.

    python benchmarks/compare_variant.py VARIANT [--seeds cr64-1202,cr64-seed43,...] [--rule pooled|own] [--rows FILE]
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

ROWS = Path(__file__).parent / "results" / "all-views" / "rows-l2.jsonl"


def load(path: Path, views: int = 16) -> dict[tuple[str, str], dict]:
    """The rows of ``views`` views by (object, variant); a malformed line raises ``LookupError``."""
    rows = {}
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
            if row.get("views") == views:
                rows[(row["object"], row.get("variant", ""))] = row
        except (json.JSONDecodeError, KeyError, AttributeError) as exc:
            raise LookupError(f"{path} line {number} is not a row ({exc})") from None
    return rows


RULES = ("pooled", "own")
SEEDS = "cr64-1202,cr64-seed43,cr64-seed44,cr64-seed45"
"""Today's 16-view default, four ray-sampler seeds (42-45)."""


def seed_spread(runs: list[dict]) -> tuple[float, float]:
    """How far the seeds' rows of one object lie apart, averaged over their pairs: |PSNR difference| (dB)
    and |CD ratio - 1| (%)."""
    pairs = list(itertools.combinations(runs, 2))
    return (sum(abs(a["psnr"] - b["psnr"]) for a, b in pairs) / len(pairs),
            sum(abs(a["cd"] / b["cd"] - 1) * 100 for a, b in pairs) / len(pairs))


def table(rows: dict[tuple[str, str], dict], variant: str, seeds: list[str], rule: str = "pooled") -> list[str]:
    """The markdown lines: per object, ``variant`` against the mean of ``seeds`` (two or more variants)."""
    if len(seeds) < 2:
        raise LookupError(f"--seeds needs two or more variants, got {','.join(seeds)!r}")
    seeded_objects = sorted({o for (o, v) in rows if v == seeds[0] and all((o, s) in rows for s in seeds)})
    objects = [o for o in seeded_objects if (o, variant) in rows]
    if not objects:
        raise LookupError(f"no object has rows of {variant!r} and of {', '.join(map(repr, seeds))}")
    spreads = {o: seed_spread([rows[(o, s)] for s in seeds]) for o in seeded_objects}
    pooled = tuple(sum(spread[k] for spread in spreads.values()) / len(spreads) for k in (0, 1))
    lines = ["| object | PSNR | LPIPS | CD | against the first seed (PSNR, CD) | the seeds differ by |",
             "|---|---|---|---|---|---|"]
    kept = []  # (variant row, the seeds' mean PSNR, LPIPS and CD)
    for name in objects:
        row, runs = rows[(name, variant)], [rows[(name, s)] for s in seeds]
        psnr, lpips, cd = (sum(run[k] for run in runs) / len(runs) for k in ("psnr", "lpips", "cd"))
        seed_psnr, seed_cd = spreads[name]
        limit_psnr, limit_cd = pooled if rule == "pooled" else (seed_psnr, seed_cd)
        outside = row["psnr"] - psnr < -2 * limit_psnr or (row["cd"] / cd - 1) * 100 > 2 * limit_cd
        first = runs[0]
        lines.append(f"| {name} | {row['psnr'] - psnr:+.2f} dB | {row['lpips'] - lpips:+.4f} | "
                     f"{100 * (row['cd'] / cd - 1):+.1f}% | {row['psnr'] - first['psnr']:+.2f} dB, "
                     f"{100 * (row['cd'] / first['cd'] - 1):+.1f}% | {seed_psnr:.2f} dB, {seed_cd:.1f}%"
                     f"{' **outside twice**' if outside else ''} |")
        kept.append((row, psnr, lpips, cd))
    n = len(kept)
    psnr, base_psnr = sum(k[0]["psnr"] for k in kept) / n, sum(k[1] for k in kept) / n
    lpips, base_lpips = sum(k[0]["lpips"] for k in kept) / n, sum(k[2] for k in kept) / n
    cd, base_cd = sum(k[0]["cd"] for k in kept) / n, sum(k[3] for k in kept) / n
    lines.append(f"| **mean ({n})** | {psnr:.2f} ({psnr - base_psnr:+.2f}) | {lpips:.4f} ({lpips - base_lpips:+.4f}) | "
                 f"{cd:.5f} (x{cd / base_cd:.3f}) | | |")
    if rule == "pooled":
        counted = f"{len(spreads)} object" + ("s" if len(spreads) != 1 else "")
        lines.append(f"\nRule: twice the seeds' difference averaged over {counted} ({pooled[0]:.2f} dB, "
                     f"{pooled[1]:.1f}% CD).")
    else:
        lines.append("\nRule: twice each object's own seed difference.")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("variant")
    parser.add_argument("--seeds", default=SEEDS, help="the default's runs, two or more variants (seeds)")
    parser.add_argument("--rule", choices=RULES, default="pooled",
                        help="the reseed spread an object is held to: pooled over the objects (default) or its own")
    parser.add_argument("--rows", type=Path, default=ROWS)
    args = parser.parse_args(argv)
    if not args.rows.is_file():
        print(f"error: no rows file at {args.rows}", file=sys.stderr)
        return 2
    try:
        print("\n".join(table(load(args.rows), args.variant, args.seeds.split(","), args.rule)))
    except LookupError as exc:
        print(f"error: {exc.args[0]}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
