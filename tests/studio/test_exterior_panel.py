"""Step 3's *Pose in the test field* panel on a copy of the disaster-response session (in-process studio): it names
the session's test field, lists the camera's images, resects the chosen one into a result it shows (pose, sigma,
X0/Y0/Z0 and omega/phi/kappa, verdict) with the wall drawn in 3D; with a checkerboard as the board it says the
test field is missing until step 1 sets one beside the board, and then poses the camera again."""

from __future__ import annotations

import re

import numpy as np
import pytest
import viser

from backend.core.transforms import invert, transform_error
from backend.services.demo_disaster_response import DISASTER_RESPONSE_NAME
from backend.services.jobs import JobRunner
from backend.sim.disaster_response import CAMERA
from backend.sim.marker_targets import field_views
from backend.store.session import SessionStore
from studio.app import StudioApp
from tests.conftest import disaster_response_template, fresh_demo

pytestmark = pytest.mark.slow

FIELD = "testfield:DICT_4X4_50:0.15:survey.csv"


def test_the_panel_poses_the_camera_in_the_wall_beside_a_board(tmp_path_factory, tmp_path, free_port) -> None:
    store = SessionStore(fresh_demo(disaster_response_template(tmp_path_factory), tmp_path / "sessions"))
    session = store.get(DISASTER_RESPONSE_NAME)
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    jobs = JobRunner()
    notes: list[tuple[str, str]] = []
    try:
        app = StudioApp(server, store, jobs, session=session)
        app.ctx.notify = lambda title, body, error=False: notes.append((title, body))
        panel = app.intrinsics_step.exterior
        assert app.intrinsics_step.camera.value == CAMERA and panel.camera == CAMERA
        assert panel.field_text.content == f"Test field: `{FIELD}`"
        assert panel.result_text.content == "No exterior orientation of this camera yet."
        label = next(option for option in panel.image.options if option.startswith("wall_03.png"))

        panel.image.value = label
        panel._resect()
        assert not notes, notes
        text = panel.result_text.content
        for pattern in (r"T_wall_camera: -?\d+\.\d{4}, ", r"1σ: \d+\.\d, \d+\.\d, \d+\.\d mm", r"X0, Y0, Z0: ",
                        r"ω, φ, κ: ", r"RMS \d\.\d{3} px over \d+ of \d+ markers", r"Verdict: "):
            assert re.search(pattern, text), (pattern, text)
        record = session.result(panel.history.selected)
        trans_m, rot_deg = transform_error(np.array(record["T_parent_child"]), invert(field_views()[3]))
        assert np.linalg.norm(trans_m) < 0.005 and np.linalg.norm(rot_deg) < 0.1, (trans_m, rot_deg)
        assert "/steps/intrinsics/boards/captured/0" in server.scene._handle_from_node_name  # the posed wall

        # a checkerboard as the board: the panel says what is missing, and a resect is refused with it
        app.session_step._set_target("board", "checkerboard:9x6:0.025")
        panel._resect()
        assert notes[-1][0] == "Cannot pose the camera" and "has no test field" in notes[-1][1], notes
        assert "has no test field" in panel.field_text.content

        # step 1 sets the wall beside the board: posed again, a second result in the history
        app.session_step._set_target("test field", FIELD)
        assert session.test_field == FIELD and session.board == "checkerboard:9x6:0.025"
        assert f"Test field beside it: `{FIELD}`" in app.session_step.summary.content
        panel._resect()
        assert panel.field_text.content == f"Test field: `{FIELD}`"
        assert len(panel.history.dropdown.options) == 2 and panel.history.selected != record["id"]
        app.close()
    finally:
        jobs.shutdown()
        server.stop()
