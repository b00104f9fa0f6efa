"""A screened variant of the 16-view GSO rows against the default's two seeds, object by object.

Reads ``benchmarks/results/all-views/rows-l2.jsonl`` (or ``--rows``) and prints a markdown table: per object
the variant against the two-seed mean of the default (PSNR, LPIPS, CD), against the first seed alone, and
the two seeds' own difference; objects where the variant loses more than twice that difference (the
per-object rule of the speed screens) are marked. The last line holds the means.

    python benchmarks/compare_variant.py VARIANT [--seeds cr64-1202,cr64-seed43] [--rows FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROWS = Path(__file__).parent / "results" / "all-views" / "rows-l2.jsonl"


def load(path: Path, views: int = 16) -> dict[tuple[str, str], dict]:
    rows = {}
    for line in path.read_text().splitlines():
        row = json.loads(line)
        if row.get("views") == views:
            rows[(row["object"], row.get("variant", ""))] = row
    return rows


def table(rows: dict[tuple[str, str], dict], variant: str, first: str, second: str) -> list[str]:
    objects = sorted(o for (o, v) in rows if v == variant and (o, first) in rows and (o, second) in rows)
    if not objects:
        raise LookupError(f"no object has rows of {variant!r}, {first!r} and {second!r}")
    lines = ["| object | PSNR | LPIPS | CD | against the first seed (PSNR, CD) | the two seeds differ by |",
             "|---|---|---|---|---|---|"]
    sums = {"psnr": 0.0, "lpips": 0.0, "cd": 0.0, "base_psnr": 0.0, "base_lpips": 0.0, "base_cd": 0.0}
    for name in objects:
        row, a, b = rows[(name, variant)], rows[(name, first)], rows[(name, second)]
        psnr, lpips, cd = ((a[k] + b[k]) / 2 for k in ("psnr", "lpips", "cd"))
        seed_psnr, seed_cd = abs(a["psnr"] - b["psnr"]), abs(a["cd"] / b["cd"] - 1) * 100
        outside = row["psnr"] - psnr < -2 * seed_psnr or (row["cd"] / cd - 1) * 100 > 2 * seed_cd
        lines.append(f"| {name} | {row['psnr'] - psnr:+.2f} dB | {row['lpips'] - lpips:+.4f} | "
                     f"{100 * (row['cd'] / cd - 1):+.1f}% | {row['psnr'] - a['psnr']:+.2f} dB, "
                     f"{100 * (row['cd'] / a['cd'] - 1):+.1f}% | {seed_psnr:.2f} dB, {seed_cd:.1f}%"
                     f"{' **outside twice**' if outside else ''} |")
        for key, value in (("psnr", row["psnr"]), ("lpips", row["lpips"]), ("cd", row["cd"]),
                           ("base_psnr", psnr), ("base_lpips", lpips), ("base_cd", cd)):
            sums[key] += value
    n = len(objects)
    mean = {k: v / n for k, v in sums.items()}
    lines.append(f"| **mean ({n})** | {mean['psnr']:.2f} ({mean['psnr'] - mean['base_psnr']:+.2f}) | "
                 f"{mean['lpips']:.4f} ({mean['lpips'] - mean['base_lpips']:+.4f}) | {mean['cd']:.5f} "
                 f"(x{mean['cd'] / mean['base_cd']:.3f}) | | |")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("variant")
    parser.add_argument("--seeds", default="cr64-1202,cr64-seed43", help="the default's two variants (seeds)")
    parser.add_argument("--rows", type=Path, default=ROWS)
    args = parser.parse_args(argv)
    if not args.rows.is_file():
        print(f"error: no rows file at {args.rows}", file=sys.stderr)
        return 2
    first, _, second = args.seeds.partition(",")
    try:
        print("\n".join(table(load(args.rows), args.variant, first, second)))
    except LookupError as exc:
        print(f"error: {exc.args[0]}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
