"""Live capture through the simulated camera: auto-capture, manual capture, an unplugged camera, and the demo's
front camera kept by auto-capture's rule."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from backend.calib._session import session_board
from backend.calib.board.detection import Detection
from backend.calib.intrinsics import service as intrinsics_service
from backend.services.demo import DEMO_CAMERA, DEMO_NAME
from backend.services.live_capture import LiveCallbacks, LiveCapture, coverage_from_captures, data_enough
from backend.sim.demo_rig import DEMO_BOARD, demo_rig
from backend.store.session import SessionStore
from tests.conftest import fresh_demo


class Recorder:
    """Collects what the capture thread reports."""

    def __init__(self):
        self.frames = 0
        self.captured: list[str] = []
        self.statuses: list[tuple[str, bool]] = []
        self.failed = threading.Event()

    def callbacks(self) -> LiveCallbacks:
        return LiveCallbacks(frame=self._frame, captured=self._captured, status=self._status)

    def _frame(self, frame) -> None:
        self.frames += 1

    def _captured(self, record, coverage) -> None:
        self.captured.append(record.id)

    def _status(self, message: str, error: bool) -> None:
        self.statuses.append((message, error))
        if error:
            self.failed.set()


def make_session(tmp_path, **device):
    rig = demo_rig()
    rig.get("cam_front").device = {"driver": "simulated", "camera": "cam_front", "seed": 2, **device}
    return SessionStore(tmp_path).create("live", rig=rig, board=DEMO_BOARD)


@pytest.mark.slow
def test_unplugged_camera_keeps_every_capture(tmp_path):
    session = make_session(tmp_path, disconnect_after=6)
    recorder = Recorder()
    live = LiveCapture(session, "cam_front", recorder.callbacks())
    live.start()
    assert recorder.failed.wait(60), "the disconnect was never reported"
    live.stop()
    assert not live.running
    message = next(m for m, error in recorder.statuses if error)
    assert "disconnected" in message.lower() or "unplugged" in message.lower() or "after 6" in message
    assert f"the {len(recorder.captured)} capture(s) taken so far are kept" in message
    assert recorder.frames == 6
    stored = [c.id for c in session.captures("cam_front")]
    assert stored == recorder.captured and len(stored) >= 3  # new poses add coverage: most frames are kept
    reopened = SessionStore(tmp_path).get("live")
    assert [c.id for c in reopened.captures("cam_front")] == stored
    assert all(c.detection for c in reopened.captures("cam_front"))


@pytest.mark.slow
def test_repeated_view_is_not_captured_twice_unless_asked(tmp_path):
    session = make_session(tmp_path, n_poses=1, disconnect_after=4)  # the board never moves
    recorder = Recorder()
    live = LiveCapture(session, "cam_front", recorder.callbacks())
    live.start()
    assert recorder.failed.wait(60)
    live.stop()
    assert len(session.captures("cam_front")) == 1

    recorder = Recorder()
    live = LiveCapture(make_session(tmp_path / "manual", n_poses=1, disconnect_after=3), "cam_front",
                       recorder.callbacks(), auto_capture=False)
    live.capture_now()
    live.start()
    assert recorder.failed.wait(60)
    live.stop()
    assert len(recorder.captured) == 1  # one requested frame, then nothing without auto-capture


def test_missing_device_settings_are_reported(tmp_path):
    session = make_session(tmp_path)
    session.rig.get("cam_wide").device = {}
    recorder = Recorder()
    live = LiveCapture(session, "cam_wide", recorder.callbacks())
    live.start()
    assert recorder.failed.wait(10)
    live.stop()
    assert "no capture device configured" in recorder.statuses[0][0]
    assert session.captures("cam_wide") == []


@pytest.mark.slow
def test_the_demos_front_camera_opens_on_enough_data(demo_template: Path, tmp_path: Path) -> None:
    """The demo's ``cam_front`` holds the views auto-capture keeps while the board is waved, up to full coverage
    (:mod:`backend.services.demo`, by :func:`~backend.services.live_capture.worth_keeping`): its coverage is
    full, its accepted solve (the step's default model, the front lens's own) is trusted with the worst
    projection sigma within the tolerance, so "enough data", and the lens is within 3 sigma of the truth. The
    images the demo keeps as LiDAR-camera pairs and camera sets are not lens views: one more changes nothing,
    while one more lens view asks for a solve again. The browser test of the intrinsics step walks ``cam_wide``
    live the same way, from no views."""
    session = SessionStore(fresh_demo(demo_template, tmp_path / "sessions")).get(DEMO_NAME)
    camera = DEMO_CAMERA
    captures = session.captures(camera)
    target = intrinsics_service.target_identity(session)
    lens = [capture for capture in captures if intrinsics_service.is_lens_view(capture, target)]
    assert 0 < len(lens) < len([capture for capture in captures if capture.detection])  # pairs' and sets' too
    coverage = coverage_from_captures(session, camera, session_board(session))
    assert coverage.full, coverage.missing()
    enough, missing = data_enough(session, camera, coverage)
    assert enough, missing

    record = session.results(camera, "intrinsics")[-1]
    assert session.accepted(f"{camera}/intrinsics") == record["id"]
    assert sorted(record["inputs"]) == sorted(capture.id for capture in lens)
    assert record["verdict"]["level"] == "trusted", record["verdict"]
    truth, K = demo_rig().get(camera).intrinsics.K, np.array(record["camera"]["K"])
    errors = np.array([K[0, 0] - truth[0, 0], K[1, 1] - truth[1, 1], K[0, 2] - truth[0, 2], K[1, 2] - truth[1, 2]])
    sigmas = np.array([record["std"][name] for name in ("fx", "fy", "cx", "cy")])
    print(f"{camera}: {len(lens)} lens views of {len(captures)} images, worst projection sigma "
          f"{record['projection_uncertainty']['max_px']:.3f} px, fx fy cx cy off by {errors} px, sigma {sigmas}")
    assert np.all(np.abs(errors) < 3 * sigmas), f"fx fy cx cy off by {errors} px, sigma {sigmas}"

    def store_again(capture, meta: dict) -> None:
        intrinsics_service.store_capture(session, camera, session.capture_image(camera, capture.id),
                                         Detection.from_dict(capture.detection), device="test",
                                         timestamp_s=capture.timestamp_s, meta=meta)

    store_again(captures[-1], {"paired_cloud": "lidar_top:00001"})  # a pair's image: the lens step is unmoved
    assert data_enough(session, camera, coverage) == (True, [])
    store_again(lens[-1], {})  # one view more: the solve no longer speaks for the views kept
    enough, missing = data_enough(session, camera, coverage)
    assert not enough and missing == ["solve to see the projection sigma"], missing
