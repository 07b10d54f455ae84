#!/usr/bin/env python
"""Live-cloud benchmark: preparing a 100k-point frame for the page, and what the page does while clouds stream.

What it measures, in one run:

- ``frame_ms``: the studio's per-frame work for one 100k-point scan (``LidarStep._on_frame`` minus the
  send): range window, display subset, padding to a stable length, colouring by intensity, float16
  cast. ``frame_baseline_ms``, the in-run baseline, is the least any viewer must do: one float32 copy
  of the points. ``frame_max_hz`` = 1000 / ``frame_ms`` is the rate one core could prepare frames at.
- ``frame_bytes`` / ``frame_bytes_before``: payload of one frame as sent now (float16 positions, and
  per-point colours only when colouring by intensity/height/range; one colour by sensor) against
  float32 positions with per-point colours, as before in-place updates.
- In the browser (Debian chromium, software WebGL, the same machine): ``calib-studio demo`` streams
  ``lidar_top`` and ``lidar_front`` (simulated, ~28k points each) live; ``server_hz`` is each
  stream's draw rate as the studio reports it, ``page_fps_streaming`` the frames the page paints per
  second while they stream, ``page_fps_idle`` the same page before streaming (the in-run baseline),
  ``capture_click_s`` the time from clicking *Capture clouds* to the page showing the new count, and
  ``page_fps_orbit_still`` the paint rate while the view is dragged round the captured pair (as many
  points, nothing streaming): what the renderer itself manages when every frame is a real redraw.
  ``drawn_hz`` is the rate each stream is drawn at (paced to the page: a frame is sent once the page has
  handled the one before, newer frames replacing older), and ``stop_click_s`` the time from clicking
  *Stop live* to the page saying "Not live." (both timed in the page). ``--load N`` keeps N processes
  spinning on the CPU while the page streams, as on a loaded machine. ``before_pacing`` holds today's
  figures from before pacing, at the same load.
  Idle, the page repaints nothing, so ``page_fps_idle`` is only the browser's frame clock.

Scan: the simulated yard (``LidarScene``) by a 64-beam spinning LiDAR (-25..15 deg, 0.2 deg columns),
about 115k points, with intensity. Times are the median of ``REPEATS`` runs.

Prints exactly one JSON object on stdout; progress goes to stderr. Needs the test extras (Playwright)
and /usr/bin/chromium, which ``scripts/install --test`` brings.

Usage:
    .venv/bin/python benchmarks/live_clouds.py [--load N]
"""

import argparse
import json
import re
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_util import REPEATS, log, median_time

from backend.sim.demo_rig import demo_rig
from backend.sim.lidar_scene import LidarScene
from studio import cloud_colours as cc
from studio.wizard.lidar_step import LIVE_BUCKET_POINTS, MAX_DISPLAY_POINTS

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM_ARGS = ["--headless=new", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 "--ignore-gpu-blocklist", "--disable-background-networking"]
PAINT_RATE_JS = """() => new Promise(resolve => {
    let frames = 0; const start = performance.now();
    function tick() { frames++; if (performance.now() - start < 3000) requestAnimationFrame(tick);
                      else resolve(frames / ((performance.now() - start) / 1000)); }
    requestAnimationFrame(tick);
})"""
CLICK_TO_CHANGE_JS = """([label, expected]) => new Promise(resolve => {
    const button = [...document.querySelectorAll('button')].find(b => b.innerText.trim() === label);
    const started = performance.now();
    const observer = new MutationObserver(() => {
        if (document.body.innerText.includes(expected)) { observer.disconnect(); resolve(performance.now() - started); }
    });
    observer.observe(document.body, {subtree: true, childList: true, characterData: true});
    button.click();
})"""
"""Milliseconds from clicking the button labelled ``label`` to ``expected`` showing in the page, timed in the page
(Playwright's own click waits for the button to hold still over two painted frames, which at 3 frames a second
would add more than the studio takes)."""
LIVE_RE = re.compile(r"lidar_top ([\d.]+) Hz, ([\d,]+) pts drawn(?: at ([\d.]+) Hz)? · "
                     r"lidar_front ([\d.]+) Hz, ([\d,]+) pts drawn(?: at ([\d.]+) Hz)?")
"""The live line (the draw rates only since pacing)."""
BEFORE_PACING = {0: {"page_fps_streaming": 3.54, "capture_click_s": 0.97, "stop_click_s": 0.53},
                 4: {"page_fps_streaming": 3.29, "capture_click_s": 1.63, "stop_click_s": 0.61}}
"""Today's figures (2026-12-04, this machine: 2 cores, by ``--load``) from the studio before live clouds were paced
to the page (the server sent every frame, 12 Hz per stream), measured by this script's in-page timing."""


def prepare_frame(points, intensity, T_root_sensor):
    """What the LiDAR step does to a scan before sending it (range window 0.5-60 m, colour by intensity)."""
    points, intensity = cc.range_window(points, intensity, 0.5, 60.0)
    points, intensity = cc.display_subset(points, intensity, MAX_DISPLAY_POINTS)
    points, intensity = cc.padded_to_bucket(points, intensity, LIVE_BUCKET_POINTS)
    colours = cc.colour_points("intensity", points, intensity, T_root_sensor, 0)
    return points.astype(np.float16), colours


def frame_figures():
    rig = demo_rig()
    T_base_lidar = rig.T_root_frame("lidar_top")
    scan = LidarScene().scan_3d(T_base_lidar, beams=64, vertical_fov_deg=(-25, 15), azimuth_step_deg=0.2,
                                range_noise_m=0.01, rng=np.random.default_rng(1))
    points, intensity = scan.points, scan.intensity.astype(np.float32)
    log(f"scan: {len(points):,} points")
    frame_s = median_time(lambda: prepare_frame(points, intensity, T_base_lidar), repeats=5 * REPEATS)
    baseline_s = median_time(lambda: points.astype(np.float32), repeats=5 * REPEATS)
    positions, colours = prepare_frame(points, intensity, T_base_lidar)
    n = min(len(points), MAX_DISPLAY_POINTS)
    return {
        "points": len(points),
        "frame_ms": 1000 * frame_s,
        "frame_baseline_ms": 1000 * baseline_s,
        "frame_ratio": frame_s / baseline_s,
        "frame_max_hz": 1.0 / frame_s,
        "frame_bytes": {"by_intensity": positions.nbytes + colours.nbytes, "by_sensor": positions.nbytes + 3},
        "frame_bytes_before": n * 3 * 4 + n * 3,
    }


def free_port():
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def orbit_paint_rate(page, seconds=3.0):
    """Frames painted per second while the view is dragged round a still scene (every frame a real redraw)."""
    page.evaluate("""() => { window.benchFrames = 0; const start = performance.now();
        const tick = () => { window.benchFrames++; if (performance.now() - start < 3000) requestAnimationFrame(tick); };
        requestAnimationFrame(tick); }""")
    page.mouse.move(300, 450)
    page.mouse.down()
    started = time.monotonic()
    while time.monotonic() - started < seconds + 0.5:
        page.mouse.move(300 + 200 * np.sin(time.monotonic() - started), 450)
        time.sleep(0.05)
    page.mouse.up()
    return page.evaluate("() => window.benchFrames") / seconds


def browser_figures(load: int):
    from playwright.sync_api import expect, sync_playwright

    api_port, viewer_port = free_port(), free_port()
    burners: list[subprocess.Popen] = []
    with tempfile.TemporaryDirectory() as sessions:
        studio = subprocess.Popen(
            [sys.executable, "-m", "studio.cli", "demo", "--sessions", sessions, "--port", str(api_port),
             "--viewer-port", str(viewer_port)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        try:
            url = studio.stdout.readline().strip()
            log(f"studio at {url}")
            with sync_playwright() as playwright:
                browser = playwright.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
                page = browser.new_page(viewport={"width": 1280, "height": 900})
                page.set_default_timeout(60_000)
                page.goto(url)
                expect(page.get_by_text("Connected", exact=True)).to_be_visible()
                # a fresh sessions folder: the demo is built in the background and opened when ready
                expect(page.get_by_text("Simulated rig (known ground truth)")).to_be_visible(timeout=900_000)
                time.sleep(3)
                page.get_by_text("4 · LiDARs", exact=True).click()
                for name, live in (("lidar_top", True), ("lidar_front", True), ("scanner_2d", False),
                                   ("sweep_3d", False)):
                    page.get_by_label(name, exact=True).set_checked(live)
                burners.extend(subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(load))
                idle_fps = page.evaluate(PAINT_RATE_JS)
                page.get_by_role("button", name="Start live", exact=True).click()
                page.wait_for_function(r"() => /pts drawn( at [\d.]+ Hz)? · lidar_front/.test(document.body.innerText)")
                time.sleep(4)
                streaming_fps = page.evaluate(PAINT_RATE_JS)
                rates = LIVE_RE.search(page.inner_text("body"))
                clicks = [page.evaluate(CLICK_TO_CHANGE_JS, ["Capture clouds", f"lidar_front: {count} ·"]) / 1000
                          for count in range(1, REPEATS + 1)]
                stop_s = page.evaluate(CLICK_TO_CHANGE_JS, ["Stop live", "Not live."]) / 1000
                expect(page.get_by_role("button", name="Start live", exact=True)).to_be_visible()
                time.sleep(3)  # the captured pair (as many points as the live clouds) is now drawn, still
                orbit_fps = orbit_paint_rate(page)
                browser.close()
        finally:
            for burner in burners:
                burner.kill()
            studio.terminate()
            studio.wait(30)
    capture_s = float(np.median(clicks))
    before = BEFORE_PACING.get(load)
    return {
        "server_hz": [float(rates.group(1)), float(rates.group(4))] if rates else None,
        "points_drawn": [int(rates.group(2).replace(",", "")), int(rates.group(5).replace(",", ""))] if rates else None,
        "drawn_hz": [float(rates.group(3)), float(rates.group(6))] if rates and rates.group(3) else None,
        "page_fps_streaming": streaming_fps,
        "page_fps_idle": idle_fps,
        "page_fps_ratio": streaming_fps / idle_fps,
        "page_fps_orbit_still": orbit_fps,
        "page_fps_vs_orbit": streaming_fps / orbit_fps,
        "capture_click_s": capture_s,
        "stop_click_s": stop_s,
        "before_pacing": before,
        "capture_click_vs_before": capture_s / before["capture_click_s"] if before else None,
        "stop_click_vs_before": stop_s / before["stop_click_s"] if before else None,
        "page_fps_streaming_vs_before": streaming_fps / before["page_fps_streaming"] if before else None,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--load", type=int, default=0, help="processes spinning on the CPU while the page streams")
    args = parser.parse_args()
    log("preparing 100k-point frames")
    result = frame_figures()
    log(f"streaming into a real page (load: {args.load} spinning processes)")
    result["browser"] = browser_figures(args.load) | {"load": args.load}
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
