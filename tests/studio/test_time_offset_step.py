"""Step 11, *Clocks*, in an in-process studio: a camera's and a LiDAR's captures of a simulated carried board
(37 ms apart) measured as a job, the result shown (the offset, the plot, the card) and accepted, after which the
clocks table shows the LiDAR's clock offset; a pair that cannot be measured is refused with a toast."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from backend.calib.lidar_camera.capture import store_pair
from backend.devices.base import Sample
from backend.plots.render import to_rgb
from backend.plots.time_offset import aligned_signals
from backend.services.demo import BOARD_MOTIONS, move_simulated_board, simulated_board_motion
from backend.services.motion_recording import Recording
from backend.sim.demo_rig import DEMO_BOARD, demo_rig
from backend.sim.moving_board import CAMERA, simulate_moving_board
from backend.store.session import SessionStore
from studio.wizard.simulated_board import move_board
from tests.conftest import ARTIFACTS, poll
from tests.studio.in_process import in_process_studio
from tests.time_offset_session import moving_board_session


def test_the_step_measures_shows_and_accepts_an_offset(tmp_path, free_port) -> None:
    store = SessionStore(tmp_path / "sessions")
    recording = simulate_moving_board(duration_s=12.0, offset_s=0.037, seed=4, camera_hz=10.0)
    session = moving_board_session(store, recording)
    with in_process_studio(store, session, free_port) as (app, notes):
        step = app.time_offset_step
        assert step.reference.options == ("cam", "cam2", "lidar") and step.sensor.options == ("lidar", "cam", "cam2")
        assert "| lidar | lidar3d | 0.00 | not measured |" in step.clocks_text.content

        step.sensor.value = "cam"
        step._measure()
        assert notes[-1][0] == "Cannot measure the time offset" and "name the camera first" in notes[-1][1], notes

        step.sensor.value = "lidar"
        empty = to_rgb(aligned_signals(None))
        step._measure()
        poll(lambda: step.plot.image.shape != empty.shape or (step.plot.image != empty).mean() > 0.05,
             lambda: f"no result drawn: {step.jobs.text.content}", 120)
        record = session.result(step.history.selected)
        assert abs(record["time_offset_s"] - recording.offset_s) < 2e-3, record["time_offset_s"]
        assert "Time offset **" in step.offset_text.content and "t_lidar = t_cam + offset" in step.offset_text.content
        assert "not accepted" in step.card.text.content and record["verdict"]["level"] in step.card.text.content
        ARTIFACTS.mkdir(exist_ok=True)
        assert cv2.imwrite(str(ARTIFACTS / "time_offset_plot.png"), step.plot.image[..., ::-1])

        step.card.confirm.checkbox.value = True  # needed if the verdict is check
        step.card.preview()
        assert "would" in step.card.preview_text.content, step.card.preview_text.content
        step.card.accept()
        assert session.rig.get("lidar").clock_offset_s == pytest.approx(record["time_offset_s"])
        assert f"| lidar | lidar3d | {1e3 * record['time_offset_s']:.2f} |" in step.clocks_text.content

        # a pair captured now says, in step 5, which clock offset it assumed
        image = Sample(600.0, image=np.zeros((CAMERA.height, CAMERA.width), np.uint8))
        store_pair(session, "cam", "lidar", image, Sample(600.0, points=recording.scans[0]), device="test",
                   detection=None)
        lidar_camera = app.lidar_camera_step
        lidar_camera.camera.value, lidar_camera.lidar.value = "cam", "lidar"
        lidar_camera._list_scenes()
        lidar_camera._load_scenes()
        assert f"clock offsets assumed: lidar {1e3 * record['time_offset_s']:.2f} ms" in \
            lidar_camera.data_text.content, lidar_camera.data_text.content


def test_the_simulated_board_is_carried_for_clocks_and_held_again_for_pairs(tmp_path, free_port) -> None:
    """On a simulated rig, step 11 offers to carry the yard's board without stopping; while it is carried, step 6
    offers to hold it still again (its pairs need a still board), and step 11 offers the same."""
    store = SessionStore(tmp_path / "sessions")
    session = store.create("sim", rig=demo_rig(), board=DEMO_BOARD)
    move_simulated_board(session, "cam_front", "scene")
    with in_process_studio(store, session, free_port) as (app, notes):
        clocks, pairs = app.time_offset_step, app.lidar_camera_step
        clocks.reference.value = pairs.camera.value = "cam_front"
        assert clocks.carry_button.visible and not clocks.hold_button.visible and not pairs.hold_button.visible
        assert move_board(app.ctx, "cam_front", "carried")  # what step 11's button does
        assert simulated_board_motion(session, "cam_front") == "carried"
        assert notes[-1] == ("The simulated board", f"It is now {BOARD_MOTIONS['carried']}.")
        assert pairs.hold_button.visible and clocks.hold_button.visible and not clocks.carry_button.visible
        assert move_board(app.ctx, "cam_front", "scene")  # what step 6's button does
        assert simulated_board_motion(session, "cam_front") == "scene" and not pairs.hold_button.visible
        assert not move_board(app.ctx, "lidar_top", "carried")  # not a simulated camera: said, nothing moved
        title, body = notes[-1]
        assert title == "Cannot move the simulated board" and "lidar_top is not a simulated camera" in body

        clocks._recorded(Recording("rec-20261206-120000", {"cam_front": 30, "lidar_top": 140}, {"cam_front": 2}, 10.0,
                                   {"cam_front": 3.0, "lidar_top": 14.0}))  # what a busy machine records
        title, body = notes[-1]
        assert title == "Recorded" and body.startswith("rec-20261206-120000: cam_front 30 capture(s), lidar_top 140 "
                                                       "capture(s); cam_front: 2 frame(s) without the board.")
        assert "Slow: cam_front 3.0/s, under 5/s" in body and "lidar_top 14" not in body.split("Slow:")[1]
