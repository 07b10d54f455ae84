"""Step 10, *Camera to IMU*, in an in-process studio on a session made without a board: a simulated recording's two
files uploaded, solved as a job with the ``scale-misalignment`` IMU model picked, the result shown (the time offset,
the IMU's scale found, the card with its verdict naming the other model's cross-check, the excitation and signal
plots) and kept; a solve without both files, or with a board the corners are not on, refused with a toast and
nothing kept."""

from __future__ import annotations

import re
from types import SimpleNamespace

import cv2
import pytest

from backend.core.rig import Frame, Rig
from backend.plots.camera_imu import excitation_bars, fitted_signals
from backend.plots.render import to_rgb
from backend.sim.camera_imu import CAMERA, recording_files, simulate_recording
from backend.store.session import SessionStore
from tests.conftest import ARTIFACTS, poll
from tests.studio.in_process import in_process_studio

pytestmark = pytest.mark.slow


def test_the_step_solves_an_uploaded_recording(tmp_path, free_port) -> None:
    rig = Rig()
    rig.add(Frame("cam0", "base_link", kind="camera", intrinsics=CAMERA))
    rig.add(Frame("imu0", "base_link", kind="imu"))
    store = SessionStore(tmp_path / "sessions")
    session = store.create("rig", rig=rig)  # no board: the camera-IMU step names its own
    with in_process_studio(store, session, free_port) as (app, notes):
        # a session made without a board (the API allows it) opens, and step 3 says where to set one
        assert "has no board spec yet" in app.intrinsics_step.coverage_text.content
        step = app.camera_imu_step
        assert (step.camera.value, step.imu.value) == ("cam0", "imu0")
        # 19 s: one fit, too short for the two-halves cross-check (two more fits; test_sim.py's): the step is tested
        imu_csv, detections_csv = recording_files(simulate_recording(duration_s=19.0, offset_s=0.023, seed=5))

        step._solve()
        assert notes[-1][0] == "Recording missing", notes
        step._keep("imu", SimpleNamespace(name="imu.csv", content=imu_csv))
        step._keep("detections", SimpleNamespace(name="corners.csv", content=detections_csv))
        assert "imu: `imu.csv`" in step.files_text.content and "detections: `corners.csv`" in step.files_text.content
        step.board.value = "aprilgrid:6x6:0.05:0.3"
        step._solve()
        assert notes[-1][0] == "Cannot solve camera to IMU" and "not corners of the board" in notes[-1][1], notes
        assert session.results("imu0") == []

        step.board.value = "aprilgrid:6x6:0.088:0.3"
        assert step.imu_model.options == ("calibrated", "scale-misalignment") and step.imu_model.value == "calibrated"
        step.imu_model.value = "scale-misalignment"
        step._solve()
        empty_signals = to_rgb(fitted_signals(None))
        poll(lambda: step.signals_image.image.shape != empty_signals.shape or (
            step.signals_image.image != empty_signals).mean() > 0.05,  # the last thing a result draws
             lambda: f"no result drawn: {step.jobs.text.content}", 600)
        result_id = step.history.selected
        offset = re.search(r"Time offset \*\*(-?\d+\.\d+) ms\*\* ± (\d+\.\d+)", step.offset_text.content)
        assert offset and abs(float(offset.group(1)) - 23.0) < 1.0, step.offset_text.content
        scales = re.search(r"IMU model \*\*scale-misalignment\*\*: accelerometer scale (\d\.\d+) / (\d\.\d+) / "
                           r"(\d\.\d+)", step.offset_text.content)
        assert scales and all(abs(float(v) - 1.0) < 0.005 for v in scales.groups()), step.offset_text.content
        assert "IMU model: fitted with the calibrated model instead" in step.card.text.content
        assert f"**{result_id}** (not accepted) · camera_imu · spline" in step.card.text.content
        assert "**cam0 → imu0**" in step.card.text.content and "Verdict:" in step.card.text.content
        for image, empty in ((step.excitation_image.image, excitation_bars(None)),
                             (step.signals_image.image, fitted_signals(None))):
            assert image.shape != to_rgb(empty).shape or (image != to_rgb(empty)).mean() > 0.05  # drawn, not empty
        ARTIFACTS.mkdir(exist_ok=True)
        cv2.imwrite(str(ARTIFACTS / "camera_imu_excitation.png"), step.excitation_image.image[..., ::-1])
        cv2.imwrite(str(ARTIFACTS / "camera_imu_signals.png"), step.signals_image.image[..., ::-1])
        assert [r["id"] for r in session.results("imu0", "camera_imu")] == [result_id]
