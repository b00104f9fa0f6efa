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


def table(rows: dict[tuple[str, str], dict], variant: str, first: str, second: str) -> list[str]:
    objects = sorted(o for (o, v) in rows if v == variant and (o, first) in rows and (o, second) in rows)
    if not objects:
        raise LookupError(f"no object has rows of {variant!r}, {first!r} and {second!r}")
    lines = ["| object | PSNR | LPIPS | CD | against the first seed (PSNR, CD) | the two seeds differ by |",
             "|---|---|---|---|---|---|"]
    kept = []  # (variant row, the two seeds' mean PSNR, LPIPS and CD)
    for name in objects:
        row, a, b = rows[(name, variant)], rows[(name, first)], rows[(name, second)]
        psnr, lpips, cd = ((a[k] + b[k]) / 2 for k in ("psnr", "lpips", "cd"))
        seed_psnr, seed_cd = abs(a["psnr"] - b["psnr"]), abs(a["cd"] / b["cd"] - 1) * 100
        outside = row["psnr"] - psnr < -2 * seed_psnr or (row["cd"] / cd - 1) * 100 > 2 * seed_cd
        lines.append(f"| {name} | {row['psnr'] - psnr:+.2f} dB | {row['lpips'] - lpips:+.4f} | "
                     f"{100 * (row['cd'] / cd - 1):+.1f}% | {row['psnr'] - a['psnr']:+.2f} dB, "
                     f"{100 * (row['cd'] / a['cd'] - 1):+.1f}% | {seed_psnr:.2f} dB, {seed_cd:.1f}%"
                     f"{' **outside twice**' if outside else ''} |")
        kept.append((row, psnr, lpips, cd))
    n = len(kept)
    psnr, base_psnr = sum(k[0]["psnr"] for k in kept) / n, sum(k[1] for k in kept) / n
    lpips, base_lpips = sum(k[0]["lpips"] for k in kept) / n, sum(k[2] for k in kept) / n
    cd, base_cd = sum(k[0]["cd"] for k in kept) / n, sum(k[3] for k in kept) / n
    lines.append(f"| **mean ({n})** | {psnr:.2f} ({psnr - base_psnr:+.2f}) | {lpips:.4f} ({lpips - base_lpips:+.4f}) | "
                 f"{cd:.5f} (x{cd / base_cd:.3f}) | | |")
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
