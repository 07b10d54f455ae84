#!/usr/bin/env python
"""Capture-click benchmark: how long a cloud capture and a LiDAR-camera pair capture keep the user waiting.

What it measures, in one run, on a copy of the demo session (built here first, in a temporary folder):

- ``cloud_click_s``: the studio's *Capture clouds* click (``LidarStep._capture``: store the latest scan of each
  live LiDAR, recount, redraw the LiDAR-to-LiDAR pair) while ``lidar_top`` and ``lidar_front`` stream live, in a
  studio built on a viser server in this process (no browser: ``benchmarks/live_clouds.py`` times the click in
  the page). In-run baseline ``raw_scan_s``: one raw simulated ``lidar_top`` scan (``SimulatedLidar.read``).
- ``pair_click_s``: a *Capture pair* of ``cam_front`` and ``lidar_top`` (``capture_pair_from_devices``, what the
  studio's job and the API's ``/lidar-camera/capture`` run: open both devices, read a frame, a scan and a frame,
  detect the board in the first with the accurate detector and in the second with the fast preview one, check it
  held still, store both), the board held still ``board_hold_s`` =
  3 s at each pose as in the demo; ``pair_clicks_s`` lists every click and ``pair_tries`` how many reads the
  hold-still check needed for each (the demo build in this process rendered most poses already). In-run
  baselines: ``raw_frame_s``, one raw simulated ``cam_front`` frame of a pose already rendered, and
  ``detection_s``, one accurate board detection in it: a pair waits for at least one of each.
- ``yard_render_s`` against ``yard_render_whole_s``: one new board pose's photograph as the simulated camera
  renders it now (the yard without the board cast once per camera, only the board's rays per pose) and as
  before (the whole scene, ``render_scene_image``).

Times are medians of ``REPEATS`` runs. Prints exactly one JSON object on stdout; progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/capture_clicks.py
"""

import contextlib
import json
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

from bench_util import REPEATS, log, median_time

from backend.calib.board.detection import detect_board
from backend.calib.lidar_camera.capture import capture_pair_from_devices
from backend.core.boards import BoardSpec
from backend.devices.base import create_device
from backend.services.demo import DEMO_CAMERA, DEMO_LIDAR, ensure_demo_session
from backend.sim.demo_rig import DEMO_BOARD, demo_rig
from backend.sim.lidar_scene import LidarScene, moving_board_poses
from backend.sim.scene_camera import clean_yard_image, render_scene_image
from backend.store.session import SessionStore


def cloud_click(sessions: Path) -> dict:
    import viser

    from backend.services.jobs import JobRunner
    from studio.app import StudioApp

    store = SessionStore(sessions)
    with contextlib.redirect_stdout(sys.stderr):  # viser's banner: stdout holds only the JSON
        server = viser.ViserServer(port=0, verbose=False)
    jobs = JobRunner()
    studio = StudioApp(server, store, jobs, store.get("demo"))
    step = studio.lidar_step
    try:
        for name, box in step.show.items():
            box.value = name in ("lidar_top", "lidar_front")
        step.start_live()
        while any(thread.latest is None for thread in step.live.values()):
            time.sleep(0.1)
        time.sleep(2)  # streaming steadily
        clicks = []
        for _ in range(REPEATS):
            started = time.perf_counter()
            step._capture()
            clicks.append(time.perf_counter() - started)
            time.sleep(0.5)
        rates = {name: round(thread.rate_hz, 1) for name, thread in step.live.items()}
    finally:
        step.stop_live()
        studio.close()
        jobs.shutdown()
        server.stop()
    with create_device(store.get("demo").rig.get("lidar_top").device) as lidar:
        raw_scan_s = median_time(lidar.read)
    return {"cloud_click_s": round(statistics.median(clicks), 3), "raw_scan_s": round(raw_scan_s, 3),
            "cloud_click_over_raw_scan": round(statistics.median(clicks) / raw_scan_s, 2), "live_hz": rates}


def pair_click(sessions: Path) -> dict:
    session = SessionStore(sessions).get("demo")
    clicks, tries = [], []
    for _ in range(REPEATS):
        reads = []
        started = time.perf_counter()
        capture_pair_from_devices(session, DEMO_CAMERA, DEMO_LIDAR, progress=lambda f, m, reads=reads: reads.append(m))
        clicks.append(time.perf_counter() - started)
        tries.append(len(reads))
    with create_device(session.rig.get(DEMO_CAMERA).device) as camera:
        frame = camera.read()
        raw_frame_s = median_time(camera.read)
    board = BoardSpec.parse(DEMO_BOARD)
    detection_s = median_time(lambda: detect_board(frame.image, board))
    click = statistics.median(clicks)
    return {"pair_click_s": round(click, 3), "pair_clicks_s": [round(c, 2) for c in clicks], "pair_tries": tries,
            "raw_frame_s": round(raw_frame_s, 3), "detection_s": round(detection_s, 3),
            "pair_click_over_detection": round(click / detection_s, 2)}


def yard_render() -> dict:
    rig = demo_rig()
    camera, T_base_camera = rig.get("cam_right").intrinsics, rig.T_root_frame("cam_right")
    poses = iter(moving_board_poses(12, seed=5))  # poses no demo device has rendered in this process
    clean_yard_image(next(poses), DEMO_BOARD, camera, T_base_camera, 5)  # the yard of this camera, cast once
    fast = median_time(lambda: clean_yard_image(next(poses), DEMO_BOARD, camera, T_base_camera, 5))
    pose = next(poses)
    whole = median_time(lambda: render_scene_image(LidarScene(pose), camera, T_base_camera, 5, supersample=1,
                                                   noise_sigma=0.0))
    return {"yard_render_s": round(fast, 3), "yard_render_whole_s": round(whole, 3),
            "yard_render_speedup": round(whole / fast, 1)}


def main():
    with tempfile.TemporaryDirectory() as folder:
        template = Path(folder) / "template"
        log("building the demo session ...")
        ensure_demo_session(SessionStore(template))
        figures = {}
        log("cloud capture clicks ...")
        shutil.copytree(template, Path(folder) / "clouds")
        figures |= cloud_click(Path(folder) / "clouds")
        log("pair capture clicks ...")
        shutil.copytree(template, Path(folder) / "pairs")
        figures |= pair_click(Path(folder) / "pairs")
    log("yard renders ...")
    figures |= yard_render()
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
