"""An open studio follows changes saved to its session by others (the API, the CLI's server): a sensor added,
moved or removed through the services shows in the 3D view and the sensors step without touching the page."""

from __future__ import annotations

import numpy as np
import viser

from backend.calib.rig import service as rig_service
from backend.core.rig import Frame
from backend.core.transforms import make_T
from backend.services.jobs import JobRunner
from backend.store.session import SessionStore
from studio.app import StudioApp


def test_the_studio_follows_changes_made_elsewhere(tmp_path, free_port):
    store = SessionStore(tmp_path)
    session = store.create("s")
    session.add_sensor(Frame("cam", "base_link", kind="camera"))
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    jobs = JobRunner()
    try:
        app = StudioApp(server, store, jobs, session=session)
        nodes = server.scene._handle_from_node_name
        assert "/rig/cam" in nodes and "/rig/spare" not in nodes

        # as POST /api/sessions/s/sensors would, on a request's thread: the new frame and the step's list follow
        rig_service.add_sensor(session, Frame("spare", "base_link", make_T(np.eye(3), np.array([0.5, 0.0, 0.2]))),
                               connected=False)
        assert "/rig/spare" in server.scene._handle_from_node_name
        assert "spare" in app.sensors_step.sensor.options

        # as PATCH would: the frame moves in the 3D view
        edit = rig_service.SensorEdit(T_mount=make_T(np.eye(3), np.array([0.5, 0.3, 0.2])))
        rig_service.edit_sensor(session, "spare", edit)
        np.testing.assert_allclose(server.scene._handle_from_node_name["/rig/spare"].position, (0.5, 0.3, 0.2),
                                   atol=1e-9)

        # as DELETE would: the frame and the list entry go
        rig_service.remove_sensor(session, "spare")
        assert "/rig/spare" not in server.scene._handle_from_node_name
        assert "spare" not in app.sensors_step.sensor.options
        assert "/rig/cam" in server.scene._handle_from_node_name
        app.close()
    finally:
        jobs.shutdown()
        server.stop()
