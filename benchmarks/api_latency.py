#!/usr/bin/env python
"""API latency benchmark: how fast ``/api/health`` answers while the server imports a 13-image upload.

The server runs as its own process on 127.0.0.1 (uvicorn, as ``calib-studio serve`` runs it), over a
fresh sessions folder. The client polls ``GET /api/health`` one request after another:

- ``idle``: with nothing else to do (the in-run baseline);
- ``upload``: while ``POST .../captures`` imports the 13 real 640x480 board images of
  ``opencv_stereo_chessboard`` (decode, board detection, store) through the route as it is now, which runs
  that work in the threadpool;
- ``inline``: the same import run inside an ``async def`` route on the event loop, as the route did before
  (a route added to this benchmark's server only), to show what the threadpool saves.

Each figure is the p50, p95 and max of the health latencies (ms) over ``UPLOADS`` uploads, with the p50 and
max as ratios to idle's p50; ``load_average_1min`` says how busy the machine was (the figures are only
comparable within one run).
Prints exactly one JSON object on stdout; progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/api_latency.py
"""

import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import httpx
from bench_util import log

ROOT = Path(__file__).resolve().parents[1]
IMAGES = sorted((ROOT.parent / "shared" / "data" / "opencv_stereo_chessboard").glob("left*.jpg"))
UPLOADS = 3
IDLE_REQUESTS = 200
BOARD = "checkerboard:9x6:0.025"

SERVER = """
import sys
from typing import Annotated

import uvicorn
from fastapi import File, UploadFile

from backend.api.app import create_app
from backend.calib.intrinsics import service as intrinsics

app = create_app(sys.argv[1])


@app.post("/bench/inline/{name}/{sensor}")
async def inline_upload(name: str, sensor: str, files: Annotated[list[UploadFile], File()]) -> dict:
    payload = [(f.filename, await f.read()) for f in files]  # the route as it was: all on the event loop
    report = intrinsics.import_images(app.state.studio.store.get(name), sensor, payload)
    return {"added": len(report.added)}


uvicorn.run(app, host="127.0.0.1", port=int(sys.argv[2]), log_level="warning")
"""


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def health_ms(client: httpx.Client) -> float:
    start = time.perf_counter()
    response = client.get("/api/health")
    response.raise_for_status()
    return (time.perf_counter() - start) * 1000


def summary(latencies: list[float], idle_p50: float | None = None) -> dict:
    figures = {"p50_ms": round(statistics.median(latencies), 2),
               "p95_ms": round(statistics.quantiles(latencies, n=20, method="inclusive")[-1], 2),
               "max_ms": round(max(latencies), 2), "requests": len(latencies)}
    if idle_p50 is not None:
        figures |= {"p50_ratio_to_idle": round(figures["p50_ms"] / idle_p50, 2),
                    "max_ratio_to_idle": round(figures["max_ms"] / idle_p50, 2)}
    return figures


def during_uploads(client: httpx.Client, label: str, path_of: Callable[[str], str]) -> tuple[list[float], list[float]]:
    """Health latencies (ms) while each of ``UPLOADS`` uploads runs, and each upload's wall time (s)."""
    files = [("files", (p.name, p.read_bytes(), "image/jpeg")) for p in IMAGES]
    latencies, upload_s = [], []
    for i in range(UPLOADS):
        camera = f"{label}{i}"
        client.post("/api/sessions/bench/sensors", json={"name": camera}).raise_for_status()
        done = threading.Event()

        def send(camera: str = camera, done: threading.Event = done) -> None:
            start = time.perf_counter()
            with httpx.Client(base_url=client.base_url, timeout=600) as uploader:
                uploader.post(path_of(camera), files=files).raise_for_status()
            upload_s.append(time.perf_counter() - start)
            done.set()

        thread = threading.Thread(target=send)
        thread.start()
        time.sleep(0.05)  # let the upload's body reach the server first
        while not done.is_set():
            latencies.append(health_ms(client))
        thread.join()
    return latencies, upload_s


def threadpool_route(camera: str) -> str:
    return f"/api/sessions/bench/sensors/{camera}/captures"


def inline_route(camera: str) -> str:
    return f"/bench/inline/bench/{camera}"


def main() -> None:
    if len(IMAGES) != 13:
        sys.exit(f"expected the 13 left images of opencv_stereo_chessboard beside the checkout, found {len(IMAGES)}")
    port = free_port()
    with tempfile.TemporaryDirectory() as sessions:
        server = subprocess.Popen([sys.executable, "-c", SERVER, sessions, str(port)], cwd=ROOT)
        try:
            with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=600) as client:
                for _ in range(300):
                    try:
                        client.get("/api/health")
                        break
                    except httpx.TransportError:
                        time.sleep(0.1)
                client.post("/api/sessions", json={"name": "bench", "board": BOARD}).raise_for_status()
                log(f"idle: {IDLE_REQUESTS} health requests")
                for _ in range(20):  # warm up the connection and the server's first requests
                    health_ms(client)
                idle = [health_ms(client) for _ in range(IDLE_REQUESTS)]
                idle_p50 = statistics.median(idle)
                log(f"during {UPLOADS} uploads of {len(IMAGES)} images (threadpool route)")
                upload, upload_s = during_uploads(client, "threadpool", threadpool_route)
                log(f"during {UPLOADS} uploads of {len(IMAGES)} images (inline async route, as before)")
                inline, inline_s = during_uploads(client, "inline", inline_route)
        finally:
            server.terminate()
            server.wait(timeout=30)
    print(json.dumps({
        "images_per_upload": len(IMAGES), "uploads": UPLOADS, "load_average_1min": round(os.getloadavg()[0], 1),
        "health_idle": summary(idle),
        "health_during_upload": summary(upload, idle_p50) | {"upload_s": round(statistics.median(upload_s), 2)},
        "health_during_inline_upload_before": summary(inline, idle_p50)
        | {"upload_s": round(statistics.median(inline_s), 2)},
    }, indent=2))


if __name__ == "__main__":
    main()
