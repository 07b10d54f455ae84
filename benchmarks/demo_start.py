#!/usr/bin/env python
"""Demo-start benchmark: how long ``calib-studio demo`` keeps a first-time user from the page.

What it measures, in one run:

- ``url_s``, ``page_s``: from starting ``calib-studio demo`` on an empty sessions folder to its first stdout
  line (the URL) and to the studio page answering 200. The demo session is then being built in the background;
  ``demo_ready_s`` is when the API lists it (the studio opens it then).
- The in-run baseline, the old synchronous start, which built the demo before serving: ``sync_build_s``, the
  build alone (``ensure_demo_session`` on an empty folder, in this process), plus ``page_built_s``, the start of
  ``calib-studio demo`` on a folder already holding the demo (what the old start did after its build):
  ``sync_page_s`` = their sum. ``page_over_sync`` = ``page_s`` / ``sync_page_s``.

Prints exactly one JSON object on stdout; progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/demo_start.py
"""

import json
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
from bench_util import log

from backend.services.demo import DEMO_NAME, ensure_demo_session
from backend.store.session import SessionStore

ROOT = Path(__file__).resolve().parents[1]


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_demo(sessions: Path, wait_for_demo: bool) -> dict:
    """Start ``calib-studio demo`` on ``sessions``; seconds to the URL line, the page, and (optionally) the demo."""
    api_port, viewer_port = free_port(), free_port()
    started = time.perf_counter()
    studio = subprocess.Popen(
        [sys.executable, "-m", "studio.cli", "demo", "--sessions", str(sessions), "--port", str(api_port),
         "--viewer-port", str(viewer_port)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        url = studio.stdout.readline().strip()
        figures = {"url_s": time.perf_counter() - started}
        while True:
            try:
                if httpx.get(url, timeout=5).status_code == 200:
                    break
            except httpx.TransportError:
                time.sleep(0.05)
        figures["page_s"] = time.perf_counter() - started
        while wait_for_demo:
            try:  # the page (viser) may answer before the API has bound its port
                names = [entry["name"] for entry in httpx.get(f"http://127.0.0.1:{api_port}/api/sessions").json()]
            except httpx.TransportError:
                names = []
            if DEMO_NAME in names:
                figures["demo_ready_s"] = time.perf_counter() - started
                break
            time.sleep(0.5)
        return figures
    finally:
        studio.terminate()
        studio.wait(30)


def main():
    with tempfile.TemporaryDirectory() as folder:
        log("calib-studio demo on an empty folder ...")
        fresh = start_demo(Path(folder) / "fresh", wait_for_demo=True)
        log("the old synchronous start: the build, then the start on the built demo ...")
        started = time.perf_counter()
        ensure_demo_session(SessionStore(Path(folder) / "sync"))
        sync_build_s = time.perf_counter() - started
        built = start_demo(Path(folder) / "sync", wait_for_demo=False)
    sync_page_s = sync_build_s + built["page_s"]
    print(json.dumps({
        "url_s": round(fresh["url_s"], 2), "page_s": round(fresh["page_s"], 2),
        "demo_ready_s": round(fresh["demo_ready_s"], 2), "sync_build_s": round(sync_build_s, 2),
        "page_built_s": round(built["page_s"], 2), "sync_page_s": round(sync_page_s, 2),
        "page_over_sync": round(fresh["page_s"] / sync_page_s, 3)}))


if __name__ == "__main__":
    main()
