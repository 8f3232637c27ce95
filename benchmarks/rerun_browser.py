"""Browser check: Rerun's web viewer, in headless Chromium, draws a recording of ``nbvdata demo``.

Writes a recording (``nbvdata demo --rerun``, the built-in mug, a few scans), serves it with
``rerun --serve-web`` on free local ports, opens the viewer in Debian's headless Chromium through
its chromedriver (the W3C WebDriver protocol over HTTP, no other package), waits until the 3D view
is drawn, saves a screenshot and checks that it is not empty: the 3D view's region must hold many
colours, not only the background. Every process it starts (the rerun server, chromedriver and
its Chromium) runs in a process group of its own and is killed at the end, also on failure; a
process that left its group is found by this run's temporary folder in its command line.

Outside the test run (it needs ``apt-get install chromium chromium-driver``, and a minute):

    python benchmarks/rerun_browser.py [--out docs/rerun.png] [--scans 6] [--timeout 240]

Headless Chromium has no GPU: WebGL comes from SwiftShader (``--use-angle=swiftshader
--enable-unsafe-swiftshader``), so the first frames take a while on a busy machine.
"""

from __future__ import annotations

import argparse
import base64
import io
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from contextlib import ExitStack
from pathlib import Path

import numpy as np
from PIL import Image

from nbvdata.cli import main as nbvdata_main

WINDOW = (1400, 1000)
CHROMIUM_FLAGS = ["--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-breakpad",
                  "--disable-crash-reporter", "--no-first-run", "--use-angle=swiftshader",
                  "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist", "--enable-webgl",
                  f"--window-size={WINDOW[0]},{WINDOW[1]}"]


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def start(command: list[str], stack: ExitStack, log: Path) -> subprocess.Popen:
    """Start ``command`` in a process group of its own, killed (the whole group) when ``stack``
    closes."""
    handle = open(log, "wb")
    process = subprocess.Popen(command, stdout=handle, stderr=subprocess.STDOUT, start_new_session=True)
    stack.callback(handle.close)
    stack.callback(stop, process)
    return process


def stop(process: subprocess.Popen) -> None:
    """SIGTERM to the process group, SIGKILL to what is left of it after 5 s; returns once the
    whole group is gone (RuntimeError if it is not, 10 s after that)."""
    for sig, seconds in ((signal.SIGTERM, 5.0), (signal.SIGKILL, 10.0)):
        try:
            os.killpg(process.pid, sig)
        except ProcessLookupError:
            return
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            process.poll()  # reap the leader; its children go to init, which reaps them
            if not group_alive(process.pid):
                return
            time.sleep(0.1)
    raise RuntimeError(f"process group {process.pid} ({process.args[0]}) survived SIGKILL")


def group_alive(group: int) -> bool:
    try:
        os.killpg(group, 0)
    except ProcessLookupError:
        return False
    return True


def ours(folder: Path) -> list[int]:
    """Processes whose command line names ``folder`` (this run's own temporary folder: the rerun
    server reads its recording there, every Chromium process, crash handlers included, has its
    profile there), this one left out."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and int(entry.name) != os.getpid():
            try:
                if str(folder).encode() in (entry / "cmdline").read_bytes():
                    pids.append(int(entry.name))
            except OSError:  # gone meanwhile
                pass
    return pids


def sweep(folder: Path) -> None:
    """After the process groups are stopped: wait up to 10 s for any process of ours that left
    its group (Chromium's crash handlers start sessions of their own) to exit, then kill it."""
    deadline = time.monotonic() + 10
    while (left := ours(folder)) and time.monotonic() < deadline:
        time.sleep(0.2)
    for pid in left:
        print(f"rerun_browser: killing left-over process {pid}", file=sys.stderr)
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def wait_for_port(port: int, seconds: float, process: subprocess.Popen, name: str) -> None:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"{name} exited with status {process.returncode} before listening on {port}")
        with socket.socket() as probe:
            if probe.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.25)
    raise RuntimeError(f"{name} did not listen on port {port} within {seconds:.0f} s")


def webdriver(port: int, method: str, path: str, body: dict | None = None) -> dict:
    """One WebDriver call to chromedriver -> its JSON ``value``."""
    request = urllib.request.Request(f"http://127.0.0.1:{port}{path}", method=method,
                                     data=json.dumps(body).encode() if body is not None else None,
                                     headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(request, timeout=120) as answer:
            return json.loads(answer.read())["value"]
    except urllib.error.HTTPError as error:
        raise RuntimeError(f"chromedriver {method} {path}: {error.read().decode(errors='replace')[:500]}") from None


def view_region(image: np.ndarray) -> np.ndarray:
    """The middle of the window, where the first 3D view lies (left of centre, upper part)."""
    height, width = image.shape[:2]
    return image[int(0.15 * height):int(0.6 * height), int(0.25 * width):int(0.6 * width)]


def drawn(image: np.ndarray) -> tuple[bool, int, float]:
    """(whether the 3D view region shows a drawing, its distinct colours, its pixel std)."""
    region = view_region(image)[..., :3].reshape(-1, 3)
    colours = len(np.unique(region // 8, axis=0))
    spread = float(region.std(axis=0).mean())
    return colours >= 40 and spread >= 8.0, colours, spread


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("docs/rerun.png"), help="screenshot to write")
    parser.add_argument("--scans", type=int, default=6, help="scans of the demo recording")
    parser.add_argument("--timeout", type=float, default=240.0, help="seconds to wait for the drawing")
    args = parser.parse_args(argv)
    for tool in ("rerun", "chromium", "chromedriver"):
        if shutil.which(tool) is None:
            print(f"rerun_browser: {tool} not found: pip install -e '.[viz]'; apt-get install chromium "
                  "chromium-driver", file=sys.stderr)
            return 2
    with tempfile.TemporaryDirectory() as folder, ExitStack() as stack:
        folder = Path(folder)
        stack.callback(sweep, folder)  # runs last
        recording = folder / "demo.rrd"
        status = nbvdata_main(["demo", "--scans", str(args.scans), "--out", str(folder / "demo.png"),
                               "--rerun", str(recording)])
        if status:
            return status
        web, grpc, driver = free_port(), free_port(), free_port()
        server = start(["rerun", "--serve-web", "--bind", "127.0.0.1", "--web-viewer-port", str(web),
                        "--port", str(grpc), "--hide-welcome-screen", str(recording)], stack, folder / "rerun.log")
        chromedriver = start(["chromedriver", f"--port={driver}"], stack, folder / "chromedriver.log")
        wait_for_port(web, 60, server, "rerun --serve-web")
        wait_for_port(driver, 60, chromedriver, "chromedriver")
        session = webdriver(driver, "POST", "/session", {"capabilities": {"alwaysMatch": {
            "goog:chromeOptions": {"binary": shutil.which("chromium"),
                                   "args": CHROMIUM_FLAGS + [f"--user-data-dir={folder / 'chromium'}"]}}}})["sessionId"]
        stack.callback(lambda: _quietly(webdriver, driver, "DELETE", f"/session/{session}"))
        url = f"http://127.0.0.1:{web}/?url=rerun%2Bhttp://127.0.0.1:{grpc}/proxy"
        webdriver(driver, "POST", f"/session/{session}/url", {"url": url})
        began, image, ok = time.monotonic(), None, False
        while time.monotonic() - began < args.timeout:
            time.sleep(5)
            shot = base64.b64decode(webdriver(driver, "GET", f"/session/{session}/screenshot"))
            image = np.asarray(Image.open(io.BytesIO(shot)).convert("RGB"))
            ok, colours, spread = drawn(image)
            print(f"{time.monotonic() - began:5.0f} s: 3D view region {colours} colours, std {spread:.1f}")
            if ok:
                time.sleep(10)  # let the viewer settle (plots, labels) before the picture
                shot = base64.b64decode(webdriver(driver, "GET", f"/session/{session}/screenshot"))
                image = np.asarray(Image.open(io.BytesIO(shot)).convert("RGB"))
                break
        if image is not None:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            Image.fromarray(image).quantize(colors=256, method=Image.Quantize.FASTOCTREE).save(args.out,
                                                                                                optimize=True)
            print(f"wrote {args.out} ({args.out.stat().st_size // 1024} KiB)")
        if not ok:
            print(f"rerun_browser: the 3D view was still empty after {args.timeout:.0f} s; the servers' logs:",
                  file=sys.stderr)
            for log in ("rerun.log", "chromedriver.log"):
                print((folder / log).read_text(errors="replace")[-2000:], file=sys.stderr)
            return 1
    print("ok: the web viewer drew the recording's 3D view")
    return 0


def _quietly(function, *arguments) -> None:
    try:
        function(*arguments)
    except (OSError, RuntimeError):
        pass


if __name__ == "__main__":
    sys.exit(main())
