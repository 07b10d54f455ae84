"""Step 7 on the demo can be finished: it sends the user to calibrate cam_right's lens in step 3 first (the simulated
person then waves the board close), and back to the rig solve (the board carried about the yard again), which is
then accepted. In-process studio on a copy of the demo session; the lens is captured and solved through the same
services step 3's live capture uses."""

from __future__ import annotations

from pathlib import Path

import pytest
import viser

from backend.calib.intrinsics import service as intrinsics_service
from backend.calib.intrinsics.solver import IntrinsicsSettings
from backend.calib.multicam import service as multicam_service
from backend.calib.rig import service as rig_service
from backend.services.demo import DEMO_NAME, simulated_board_motion
from backend.services.jobs import JobRunner
from backend.store.session import SessionStore
from studio.app import StudioApp
from tests.conftest import capture_lens_views, fresh_demo

pytestmark = pytest.mark.slow


def test_step_7_guides_through_cam_rights_lens_and_back(demo_template: Path, tmp_path: Path, free_port) -> None:
    store = SessionStore(fresh_demo(demo_template, tmp_path / "sessions"))
    session = store.get(DEMO_NAME)
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    jobs = JobRunner()
    try:
        app = StudioApp(server, store, jobs, session=session)
        multicam, intrinsics = app.multicam_step, app.intrinsics_step
        assert multicam.cameras == ["cam_front", "cam_right"]
        assert "cam_right has no lens calibration yet" in multicam.lens_text.content
        assert not multicam.scene_button.visible  # the demo's board is in the yard, as the sets need

        intrinsics.camera.value = "cam_right"  # step 3, as the guidance says
        assert intrinsics.wave_button.visible
        intrinsics._wave_board()
        assert simulated_board_motion(session, "cam_right") == "wave" and not intrinsics.wave_button.visible
        assert multicam.scene_button.visible  # step 7 offers the yard back

        capture_lens_views(session, "cam_right", session.rig.get("cam_right").device)  # what step 3's live reads
        lens_id, _ = intrinsics_service.solve_session(session, "cam_right", IntrinsicsSettings())
        rig_service.accept(session, lens_id, confirm=True)  # as the API would: the studio follows the change
        assert multicam.lens_text.content == ""  # calibrated: no more guidance

        multicam._carry_board()
        assert simulated_board_motion(session, "cam_right") == "scene" and not multicam.scene_button.visible
        rig_id, result = multicam_service.solve_session(session, multicam.cameras)
        assert result.converged
        rig_service.accept(session, rig_id, confirm=True)  # one scene of sets: 'check', confirmed
        assert session.accepted(multicam_service.slot(multicam.cameras)) == rig_id
        app.close()
    finally:
        jobs.shutdown()
        server.stop()
