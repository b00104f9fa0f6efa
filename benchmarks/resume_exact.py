"""Does a run interrupted anywhere and resumed end exactly as an uninterrupted one?

Usage:
    python benchmarks/resume_exact.py [--methods neus,ngp,va-neus] [--at 3,8,12,19,26] [--steps 30]
                                      [--data PATH] [--mode hook|watch] [--out DIR]

For each method: one uninterrupted ``va-train METHOD --preset fast --steps N --export-mesh``, then for each
step k of ``--at`` a run interrupted in step k (SIGINT and SIGTERM alternately) and continued with
``--resume --export-mesh``. A resumed run matches when its final loss has the same bits and its
``mesh.ply`` the same bytes as the uninterrupted run's. ``--mode hook`` (default) has the process send
itself the signal at a chosen point of step k (the ``VA_TEST_SIGNALS`` hook: after the backward pass,
before the callbacks, after them, by turns); ``--mode watch`` sends it from outside once the metrics log
shows step k (where it lands in the next step is chance; this works on code without the hook too).
``va-neus`` runs with its adaptive phases forced (they switch at N/3 and 2N/3), ``ngp``'s mesh is the
level set of density 0.5 (a short run reaches no more than about 1). Without ``--data``, the
embedded default scene at 64 px. Prints a Markdown table; writes ``OUT/resume_exact.json``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SIGNALS = (signal.SIGINT, signal.SIGTERM)
POINTS = ("mid", "start", "end")
EXTRA = {"va-neus": ["--set", "pipeline.model.field.skip_consistent_scenes=false"],
         "ngp": ["--set", "pipeline.model.density_threshold=0.5"]}
"""Per method: the adaptive phases forced; ngp's mesh at a density its short run reaches (mesh only)."""


def _python_sigint() -> None:
    """In each child before it starts: SIGINT at its default, so that Python installs its Ctrl-C handler
    even when this script runs in the background (which leaves SIGINT ignored in its children)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def command(method: str, run: Path, args, resume: bool) -> list[str]:
    data = ["--data", str(args.data)] if args.data else ["--default-scene-resolution", "64"]
    return [sys.executable, "-m", "va_plugin.cli.train", method, *data, "--preset", "fast", "--steps",
            str(args.steps), "--device", "cpu", "--output-dir", str(run), "--no-progress", "--export-mesh",
            "--set", "log_every=1", *EXTRA.get(method, []), *(["--resume"] if resume else [])]


def final(run: Path) -> dict:
    """The run's last logged loss (its bits as hex) and its mesh's SHA-256."""
    records = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines() if line.strip()]
    last = [r for r in records if "loss" in r][-1]
    mesh = run / "mesh.ply"
    return {"step": last["step"], "loss": last["loss"], "loss_bits": float(last["loss"]).hex(),
            "mesh_sha256": hashlib.sha256(mesh.read_bytes()).hexdigest() if mesh.is_file() else None}


def interrupted(method: str, run: Path, args, k: int, signum: int, point: str) -> tuple[int, str]:
    """A run cut in step ``k``; its exit status and last stderr line."""
    env = dict(os.environ)
    if args.mode == "hook":
        env["VA_TEST_SIGNALS"] = f"{k}:{signal.Signals(signum).name}@{point}"
        done = subprocess.run(command(method, run, args, False), env=env, capture_output=True, text=True,
                              preexec_fn=_python_sigint)
        return done.returncode, (done.stderr.strip().splitlines() or [""])[-1]
    process = subprocess.Popen(command(method, run, args, False), env=env, stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE, text=True, preexec_fn=_python_sigint)
    log = run / "metrics.jsonl"
    while process.poll() is None:
        steps = [json.loads(line).get("step", 0) for line in log.read_text().splitlines()[-3:]
                 if line.strip().endswith("}")] if log.is_file() else []
        if steps and max(steps) >= k - 1:  # step k is under way
            process.send_signal(signum)
            break
        time.sleep(0.01)
    _, err = process.communicate()
    return process.returncode, (err.strip().splitlines() or [""])[-1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--methods", default="neus,ngp,va-neus")
    parser.add_argument("--at", default="3,8,12,19,26", help="1-based steps to interrupt in")
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--data", type=Path, default=None)
    parser.add_argument("--mode", choices=("hook", "watch"), default="hook")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="resume_exact-"))
    out.mkdir(parents=True, exist_ok=True)
    steps = [int(k) for k in args.at.split(",")]
    rows, report = [], {"steps": args.steps, "mode": args.mode, "data": str(args.data), "methods": {}}
    for method in args.methods.split(","):
        full_run = out / method / "full"
        done = subprocess.run(command(method, full_run, args, False), capture_output=True, text=True)
        if done.returncode != 0:
            print(done.stderr[-2000:], file=sys.stderr)
            return 1
        reference = final(full_run)
        cuts = []
        for i, k in enumerate(steps):
            run = out / method / f"cut-{k}"
            signum, point = SIGNALS[i % 2], POINTS[i % 3]
            status, line = interrupted(method, run, args, k, signum, point)
            resumed = subprocess.run(command(method, run, args, True), capture_output=True, text=True)
            got = final(run) if resumed.returncode == 0 else {}
            cut = {"k": k, "signal": signal.Signals(signum).name, "point": point if args.mode == "hook" else "-",
                   "exit": status, "message": line, "resume_exit": resumed.returncode, **got,
                   "same_loss": got.get("loss_bits") == reference["loss_bits"],
                   "same_mesh": got.get("mesh_sha256") == reference["mesh_sha256"]}
            cuts.append(cut)
            print(f"{method} cut in step {k} ({cut['signal']}, {cut['point']}): exit {status}, {line}; resumed: "
                  f"loss {got.get('loss')} (same bits: {cut['same_loss']}), same mesh: {cut['same_mesh']}",
                  file=sys.stderr)
        report["methods"][method] = {"reference": reference, "cuts": cuts}
        same = sum(c["same_loss"] and c["same_mesh"] for c in cuts)
        rows.append(f"| `{method}` | {reference['loss']!r} | "
                    + ", ".join(f"{c['k']} {c['signal'][3:]}" for c in cuts)
                    + f" | {sum(c['same_loss'] for c in cuts)}/{len(cuts)} | {sum(c['same_mesh'] for c in cuts)}/"
                    f"{len(cuts)} | {same}/{len(cuts)} |")
    (out / "resume_exact.json").write_text(json.dumps(report, indent=2))
    print("| method | uninterrupted final loss | cut in step (signal) | same loss bits | same mesh bytes | both |")
    print("|---|---|---|---|---|---|")
    print("\n".join(rows))
    print(f"details: {out / 'resume_exact.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
