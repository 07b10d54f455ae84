"""The board's flex the intrinsics measured is the board every later board pose is fitted to: the session's board
for the multi-camera rig, the LiDAR-camera target and the time offsets (``session_plane_board``) is bowed as the
best-determined accepted intrinsics result found it, while an intrinsics solve starts from the printed, flat spec."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from backend.calib._session import session_board, session_plane_board
from backend.calib.intrinsics.solver import IntrinsicsSettings, View, calibrate_intrinsics
from backend.calib.rig import service as rig_service
from backend.core.boards import BoardSpec
from backend.core.rig import Frame
from backend.store.session import Session, SessionStore

SPEC = "checkerboard:9x6:0.025"
FAST = IntrinsicsSettings(estimate_k3=True, jackknife=False, cross_validate=False)


@pytest.fixture(scope="module")
def records(stereo_detections) -> dict[str, dict]:
    """The left and right cameras' solves of OpenCV's real stereo set, flex solved, as the session stores them."""
    board = BoardSpec.parse(SPEC)
    return {side: calibrate_intrinsics([View(name, d) for name, d in stereo_detections[side].items()], board,
                                       (640, 480), FAST).to_record() for side in ("left", "right")}


@pytest.fixture
def session(tmp_path: Path) -> Session:
    session = SessionStore(tmp_path / "sessions").create("rig", board=SPEC, title="flex")
    for camera in ("left", "right"):
        session.add_sensor(Frame(camera, "base_link", kind="camera"))
    return session


def test_the_session_board_is_bowed_as_the_accepted_intrinsics_measured_it(session, records):
    assert session_plane_board(session, "a test").warp_m == (0.0, 0.0)  # nothing measured yet: the printed board
    left = session.add_result("left", records["left"], inputs=[])
    assert session_plane_board(session, "a test").warp_m == (0.0, 0.0)  # solved, not accepted
    rig_service.accept(session, left, confirm=True)  # "check": the cross-validation is off here
    flex = records["left"]["board_flex"]
    assert flex["status"] == "solved" and abs(flex["warp_mm"][1]) > 0.1
    np.testing.assert_allclose(session_plane_board(session, "a test").warp_m, np.array(flex["warp_mm"]) / 1e3)
    assert session_board(session).warp_m == (0.0, 0.0)  # an intrinsics solve starts from the spec
    # a second camera's measurement of the same board: the better determined one is the board's
    right = session.add_result("right", records["right"], inputs=[])
    rig_service.accept(session, right, confirm=True)
    best = min(records.values(), key=lambda record: max(record["board_flex"]["std_mm"]))
    np.testing.assert_allclose(session_plane_board(session, "a test").warp_m,
                               np.array(best["board_flex"]["warp_mm"]) / 1e3)


def test_a_flex_measured_on_another_board_is_not_applied(session, records):
    other = {**records["left"], "board": "checkerboard:9x6:0.03"}
    rig_service.accept(session, session.add_result("left", other, inputs=[]), confirm=True)
    assert session_plane_board(session, "a test").warp_m == (0.0, 0.0)
