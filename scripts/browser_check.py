"""The va-app page in a real browser: headless Chromium loads it, uploads a file, starts a run, waits for
the textured mesh, and screenshots the page and its 3D viewer.

Usage:
    python scripts/browser_check.py [--input FILE] [--quality fast] [--out PNG] [--app-arg=--steps=60 ...]

It starts ``va-app`` on a free port (runs in a temporary folder unless ``--runs``), drives Chromium over
the DevTools protocol on a pipe (``--remote-debugging-pipe``: the standard library only, no driver, no
network), and fails unless the page shows the detected format, a training step, then "Done", and the
viewer's pixels show something other than its background. Without ``--input`` the input is a zip of a
small procedural scene folder (transforms.json), trained at test sizes. ``--install`` installs Debian's
chromium with apt-get first when it is missing (as root). The last line is ``browser: 1 passed, 0
failed`` (or ``0 passed, 1 failed``), or ``browser: skipped (...)`` when no Chromium can be had.
Exit status: 0 passed or skipped, 1 failed.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import fcntl
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
import zipfile
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--disable-dev-shm-usage", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                  "--remote-debugging-pipe", "--hide-scrollbars", "--disable-crash-reporter", "--disable-breakpad"]
"""Headless, offline, software WebGL (the 3D viewer needs it without a GPU)."""
TEST_SIZES = ["--steps", "60", "--texture-size", "128", "--mesh-resolution", "48", "--turntable-frames", "8",
              "--preview-every", "20", "--threads", "1", "--set", "pipeline.datamanager.rays_per_batch=256"]
"""``va-app`` options of the default (procedural) input: a quick run."""
WIDTH, HEIGHT = 1400, 1300
STARTED = time.perf_counter()


class DevTools:
    """Chromium's DevTools protocol over the pipe pair it reads on fd 3 and writes on fd 4."""

    def __init__(self, chromium: str, profile: Path, url: str) -> None:
        to_browser, self._writer = os.pipe()
        self._reader, from_browser = os.pipe()

        def onto_3_and_4() -> None:  # in the child, before exec: the pipe ends become fds 3 and 4
            high_in, high_out = fcntl.fcntl(to_browser, fcntl.F_DUPFD, 10), fcntl.fcntl(from_browser, fcntl.F_DUPFD, 10)
            os.dup2(high_in, 3)
            os.dup2(high_out, 4)

        command = [chromium, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", f"--window-size={WIDTH},{HEIGHT}", url]
        self.process = subprocess.Popen(command, preexec_fn=onto_3_and_4, close_fds=False,
                                        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(to_browser)
        os.close(from_browser)
        self._next = 0
        self._replies: dict[int, dict] = {}
        self._ready = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()
        self.session = None

    def _read(self) -> None:
        buffer = b""
        while True:
            chunk = os.read(self._reader, 1 << 16)
            if not chunk:
                break
            buffer += chunk
            while b"\0" in buffer:
                raw, buffer = buffer.split(b"\0", 1)
                message = json.loads(raw)
                if "id" in message:
                    with self._ready:
                        self._replies[message["id"]] = message
                        self._ready.notify_all()

    def call(self, method: str, timeout: float = 60.0, **params) -> dict:
        self._next += 1
        request = {"id": self._next, "method": method, "params": params}
        if self.session is not None and not method.startswith(("Target.", "Browser.")):
            request["sessionId"] = self.session
        os.write(self._writer, json.dumps(request).encode() + b"\0")
        deadline = time.monotonic() + timeout
        with self._ready:
            while request["id"] not in self._replies:
                if not self._ready.wait(timeout=max(0.0, deadline - time.monotonic())):
                    raise TimeoutError(f"no reply to {method} in {timeout:.0f} s")
        reply = self._replies.pop(request["id"])
        if "error" in reply:
            raise RuntimeError(f"{method}: {reply['error'].get('message')}")
        return reply.get("result", {})

    def attach(self) -> None:
        """Attach to the page the browser opened."""
        for _ in range(100):
            pages = [t for t in self.call("Target.getTargets")["targetInfos"] if t["type"] == "page"]
            if pages:
                break
            time.sleep(0.1)
        self.session = self.call("Target.attachToTarget", targetId=pages[0]["targetId"], flatten=True)["sessionId"]
        self.call("Emulation.setDeviceMetricsOverride", width=WIDTH, height=HEIGHT, deviceScaleFactor=1, mobile=False)

    def evaluate(self, expression: str):
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        return result.get("result", {}).get("value")

    def text(self, element_id: str) -> str:
        return self.evaluate(f"(document.getElementById({element_id!r}) || {{}}).innerText || ''") or ""

    def wait_for(self, what: str, expression: str, timeout: float):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            value = self.evaluate(expression)
            if value:
                return value
            time.sleep(0.25)
        raise TimeoutError(f"timed out ({timeout:.0f} s) waiting for {what}")

    def upload(self, selector: str, path: Path) -> None:
        root = self.call("DOM.getDocument", depth=1)["root"]["nodeId"]
        node = self.call("DOM.querySelector", nodeId=root, selector=selector)["nodeId"]
        if not node:
            raise RuntimeError(f"no element {selector} on the page")
        self.call("DOM.setFileInputFiles", files=[str(path)], nodeId=node)

    def screenshot(self, clip: dict | None = None) -> np.ndarray:
        params = {"format": "png", "captureBeyondViewport": True}
        if clip is not None:
            params["clip"] = {**clip, "scale": 1}
        data = base64.b64decode(self.call("Page.captureScreenshot", **params)["data"])
        return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)

    def close(self) -> None:
        with contextlib.suppress(OSError, RuntimeError, TimeoutError):
            self.call("Browser.close", timeout=10)
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()


def find_chromium(install: bool) -> str | None:
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found or not install:
        return found
    for command in (["apt-get", "update", "-q"], ["apt-get", "install", "-y", "-q", "chromium"]):
        if subprocess.run(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode != 0:
            return None
    return shutil.which("chromium")


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def procedural_input(folder: Path) -> Path:
    """A zip of a small procedural scene folder: transforms_train.json and 4 views at 64 px (no held-out
    views and no true mesh, as a user's folder: nothing to score)."""
    sys.path.insert(0, str(REPO))
    from va_plugin.bench.scenes.builder import build_procedural_scene

    scene = build_procedural_scene(folder / "mug", "mug", n_views=4, resolution=64)
    info = json.loads((scene / "scene.json").read_text())
    info.pop("mesh", None)  # a user's scene folder has no true mesh to score against
    (scene / "scene.json").write_text(json.dumps(info))
    path = folder / "mug.zip"
    with zipfile.ZipFile(path, "w") as archive:
        for file in sorted(scene.rglob("*")):
            if file.is_file() and file.name not in ("mesh.ply", "transforms_test.json") and \
                    not file.name.startswith(("test_", "clean_")):
                archive.write(file, Path("mug") / file.relative_to(scene))
    return path


def start_app(port: int, runs: Path, app_args: list[str], log: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    command = [sys.executable, "-m", "va_plugin.cli.app", "--port", str(port), "--runs", str(runs), *app_args]
    server = subprocess.Popen(command, env=env, stdout=log.open("w"), stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline:
        if server.poll() is not None:
            raise RuntimeError(f"va-app exited with status {server.returncode}: {log.read_text()[-800:]}")
        try:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=5).close()
            return server
        except OSError:
            time.sleep(0.5)
    raise TimeoutError("va-app did not answer in 180 s")


def viewer_shows_something(image: np.ndarray, margin: int = 48) -> float:
    """Share of the viewer's pixels, away from its edges (its label, buttons and border), that are not
    its background (the most common color)."""
    pixels = image[margin:-margin, margin:-margin].reshape(-1, 3).astype(np.int32)
    colors, counts = np.unique(pixels // 8, axis=0, return_counts=True)
    background = colors[counts.argmax()] * 8
    return float((np.abs(pixels - background).max(axis=1) > 24).mean())


def say(text: str) -> None:
    print(f"[{time.perf_counter() - STARTED:6.1f} s] {text}", file=sys.stderr, flush=True)


def check(args, work: Path) -> dict:
    chromium = find_chromium(args.install)
    if chromium is None:
        return {"skipped": "no chromium (apt-get install chromium, as root, or --install)"}
    upload = Path(args.input).resolve() if args.input else procedural_input(work)
    say(f"input {upload.name}; starting va-app")
    app_args = list(args.app_arg) if args.app_arg or args.input else TEST_SIZES
    runs = Path(args.runs).resolve() if args.runs else work / "runs"
    port = free_port()
    server = start_app(port, runs, app_args, work / "va-app.log")
    browser = None
    began = time.perf_counter()
    try:
        say(f"va-app answers on port {port}; starting {chromium}")
        browser = DevTools(chromium, work / "profile", f"http://127.0.0.1:{port}/")
        browser.attach()
        browser.wait_for("the page", "!!document.querySelector('#upload input[type=file]')", 120)
        if args.quality != "default":
            chosen = f'document.querySelector(\'input[type=radio][value="{args.quality}"]\')'
            browser.evaluate(f"{chosen}.click()")
            browser.wait_for(f"the {args.quality} quality to be chosen", f"{chosen}.checked", 10)
        uploaded = time.perf_counter()
        browser.upload("#upload input[type=file]", upload)
        info = browser.wait_for("the detected format", "(() => { const t = document.getElementById('info')"
                                ".innerText; return /Detected|Cannot/.test(t) ? t : ''; })()", 120)
        if "Detected" not in info:
            raise RuntimeError(f"the page refused the upload: {info}")
        inspected = time.perf_counter()
        say(f"the page shows: {info.splitlines()[0]}; clicking Start")
        browser.evaluate("document.getElementById('start').click()")
        steps_seen = set()
        deadline = time.monotonic() + args.timeout
        while time.monotonic() < deadline:
            status = browser.text("status")
            if "Training step" in status:
                steps_seen.add(status.split("Training step ")[1].split(" ")[0])
            if "Done in" in status or "Failed" in status or "Cancelled" in status:
                break
            time.sleep(0.5)
        else:
            raise TimeoutError(f"no result in {args.timeout} s; the status: {browser.text('status')}")
        if "Done in" not in status:
            raise RuntimeError(f"the run did not finish: {status}")
        if f"{args.quality} quality" not in status:
            raise RuntimeError(f"the run did not train at {args.quality} quality: {status.splitlines()[0]}")
        done = time.perf_counter()
        say(f"done ({len(steps_seen)} training steps shown); waiting for the viewer to draw the mesh")
        browser.wait_for("the 3D viewer", "!!document.querySelector('#mesh canvas')", 60)
        box = browser.evaluate("(() => { const r = document.querySelector('#mesh canvas').getBoundingClientRect();"
                               " return {x: r.x + scrollX, y: r.y + scrollY, width: r.width, height: r.height}; })()")
        shown, deadline = 0.0, time.monotonic() + 90
        while time.monotonic() < deadline:
            viewer = browser.screenshot(box)
            shown = viewer_shows_something(viewer)
            if shown > 0.01:
                break
            time.sleep(1.0)
        orbitable = time.perf_counter()
        time.sleep(1.0)  # the viewer's last frame of loading
        viewer = browser.screenshot(box)
        page = browser.screenshot()
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(out), page)
        cv2.imwrite(str(out.with_name(out.stem + "_viewer" + out.suffix)), viewer)
        return {"passed": shown > 0.01, "viewer_pixels_shown": round(shown, 4), "info": info.splitlines()[0],
                "training_steps_seen": len(steps_seen), "status": status.splitlines()[-1][:200],
                "seconds": {"upload_to_inspected": round(inspected - uploaded, 1),
                            "start_to_done": round(done - inspected, 1),
                            "upload_to_orbitable_mesh": round(orbitable - uploaded, 1),
                            "whole_check": round(time.perf_counter() - began, 1)},
                "screenshot": str(out), "viewer": str(out.with_name(out.stem + "_viewer" + out.suffix))}
    finally:
        if browser is not None:
            browser.close()
        server.terminate()
        try:
            server.wait(timeout=60)
        except subprocess.TimeoutExpired:
            server.kill()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--input", help="the file to upload (default: a zip of a small procedural scene)")
    parser.add_argument("--quality", default="default", choices=("fast", "default", "accurate"))
    parser.add_argument("--out", default=str(Path(tempfile.gettempdir()) / "va-app-page.png"),
                        help="the page's screenshot (PNG); the viewer's goes beside it (_viewer)")
    parser.add_argument("--runs", help="va-app --runs (default: a temporary folder)")
    parser.add_argument("--app-arg", action="append", default=[],
                        help="an option for va-app, as --app-arg=--steps=500 (default with --input: none; "
                             "without: test sizes)")
    parser.add_argument("--timeout", type=float, default=900, help="seconds to wait for the run (default 900)")
    parser.add_argument("--install", action="store_true", help="apt-get install chromium when it is missing")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="va-browser-") as folder:
        try:
            report = check(args, Path(folder))
        except Exception as exc:  # one report line whatever broke: the page, the browser or the app
            report = {"passed": False, "error": f"{type(exc).__name__}: {exc}"}
            log = Path(folder) / "va-app.log"
            if log.is_file():
                print(log.read_text()[-3000:], file=sys.stderr)
    print(json.dumps(report, indent=2))
    if "skipped" in report:
        print(f"browser: skipped ({report['skipped']})")
        return 0
    print("browser: 1 passed, 0 failed" if report["passed"] else "browser: 0 passed, 1 failed")
    return 0 if report["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
