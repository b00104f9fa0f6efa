"""va-app against va-recon on one input: wall time from upload to an orbitable textured mesh, in a real
browser, beside ``va-recon``'s wall time on the same input and quality, run back to back.

Usage:
    python benchmarks/run_app.py INPUT [--quality fast] [--order ABBA] [--out DIR]

``A`` is one ``va-recon INPUT --quality Q`` (its whole wall time, imports included); ``B`` is one
``scripts/browser_check.py --input INPUT --quality Q`` (headless Chromium: from setting the file on the
page's upload box to the 3D viewer drawing the mesh). ``--order`` says which run when (ABBA evens out a
drift of the machine's load). Every run gets a fresh folder under ``--out``; the report (JSON on stdout
and ``OUT/report.json``) has each wall time, the ratio of the means, and whether the app's mesh files are
the bytes of va-recon's (the app's preview renders must not change the training).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
COMPARED = ("mesh.ply", "mesh.glb", "mesh_bake.png")


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}


def run_recon(source: Path, quality: str, out: Path) -> dict:
    began = time.perf_counter()
    subprocess.run([sys.executable, "-m", "va_plugin.cli.recon", str(source), "--out", str(out), "--quality", quality],
                   env=_env(), check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return {"what": "va-recon", "wall_s": round(time.perf_counter() - began, 1), "run_dir": str(out)}


def run_app(source: Path, quality: str, out: Path) -> dict:
    runs = out / "runs"
    result = subprocess.run([sys.executable, str(REPO / "scripts" / "browser_check.py"), "--input", str(source),
                             "--quality", quality, "--runs", str(runs), "--out", str(out / "page.png"),
                             "--timeout", "3600"], env=_env(), capture_output=True, text=True)
    text = result.stdout
    report = json.loads(text[text.index("{"):text.rindex("}") + 1])
    if result.returncode != 0 or not report.get("passed"):
        raise RuntimeError(f"the browser check failed: {report}\n{result.stderr[-2000:]}")
    run_dir = next(p for p in runs.iterdir() if p.is_dir()) / "run"  # the job folder's run folder
    return {"what": "va-app", "wall_s": report["seconds"]["upload_to_orbitable_mesh"], "run_dir": str(run_dir),
            "seconds": report["seconds"]}


def same_files(a: Path, b: Path) -> dict[str, bool]:
    return {name: (a / name).read_bytes() == (b / name).read_bytes() for name in COMPARED
            if (a / name).is_file() and (b / name).is_file()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("input", type=Path)
    parser.add_argument("--quality", default="default", choices=("fast", "default", "accurate"))
    parser.add_argument("--order", default="AB", help="A: va-recon, B: va-app, in this order (default AB)")
    parser.add_argument("--out", type=Path, default=Path("outputs/run_app"))
    args = parser.parse_args()
    rows = []
    for index, which in enumerate(args.order.upper()):
        folder = args.out / f"{index}-{which}-{args.quality}"
        row = (run_recon if which == "A" else run_app)(args.input.resolve(), args.quality, folder.resolve())
        rows.append({**row, "load_1min": round(os.getloadavg()[0], 2)})
        print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    recon = [r["wall_s"] for r in rows if r["what"] == "va-recon"]
    app = [r["wall_s"] for r in rows if r["what"] == "va-app"]
    report = {"input": str(args.input), "quality": args.quality, "order": args.order, "runs": rows}
    if recon and app:
        report["ratio_app_to_recon"] = round((sum(app) / len(app)) / (sum(recon) / len(recon)), 3)
        first = {r["what"]: Path(r["run_dir"]) for r in reversed(rows)}
        report["app_files_same_as_recon"] = same_files(first["va-recon"], first["va-app"])
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
