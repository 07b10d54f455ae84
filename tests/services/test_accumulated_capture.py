"""A static Livox (the byte-level simulator, an Avia in the yard) accumulated into one capture: through the service,
the API (a job; also as the cloud of a LiDAR-camera pair) and the LiDAR step's panel in an in-process studio; the
coverage grows with the integration time, and what cannot be accumulated is refused naming it."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.core.errors import InputError
from backend.core.rig import Frame, Rig
from backend.plots.accumulation import coverage_image
from backend.plots.render import to_rgb
from backend.services.accumulated_capture import capture_accumulated
from backend.sim.demo_rig import demo_rig
from backend.store.session import SessionStore
from tests.conftest import poll, wait_job
from tests.studio.in_process import in_process_studio


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    store = SessionStore(tmp_path_factory.mktemp("accumulate") / "sessions")
    rig = Rig()
    rig.add(Frame("livox", "base_link", demo_rig().T_root_frame("lidar_front"), kind="lidar3d",
                  device={"driver": "livox", "host": "sim"}))
    rig.add(Frame("bare", "base_link", kind="lidar3d"))
    rig.add(Frame("cam", "base_link", kind="camera", device={"driver": "simulated", "camera": "cam_front"}))
    store.create("rig", rig=rig)
    return store


def test_the_coverage_grows_with_the_integration_time(store) -> None:
    session = store.get("rig")
    short, long = (capture_accumulated(session, "livox", seconds) for seconds in (0.1, 0.6))
    print(f"Livox coverage: {100 * short.coverage.share:.1f} % in 0.1 s, {100 * long.coverage.share:.1f} % in 0.6 s")
    assert short.coverage.share < long.coverage.share and long.coverage.share > 0.6
    assert long.record.n_points > 3 * short.record.n_points
    assert long.record.meta["integration_s"] == 0.6 and long.record.meta["coverage"] == long.coverage.share
    assert long.record.meta["frames"] >= 5 and long.record.source == "0.6 s accumulated"
    points, intensity = session.capture_cloud("livox", long.record.id)
    assert len(points) == long.record.n_points and intensity is not None

    with pytest.raises(InputError, match="bare has no capture device"):
        capture_accumulated(session, "bare", 0.5)
    with pytest.raises(InputError, match="integration time must be a number of seconds in"):
        capture_accumulated(session, "livox", 120.0)


def test_the_api_accumulates_as_a_job(store) -> None:
    with TestClient(create_app(store.root)) as client:
        started = client.post("/api/sessions/rig/sensors/livox/accumulate", json={"integration_s": 0.3})
        assert started.status_code == 202, started.text
        job = wait_job(client, started.json()["id"])
        assert job["state"] == "done" and 0.3 < job["summary"]["coverage"] <= 1, job
        assert job["summary"]["capture"]["n_points"] > 0
        refused = client.post("/api/sessions/rig/sensors/bare/accumulate", json={"integration_s": 0.3})
        assert refused.status_code == 422 and "no capture device" in refused.json()["error"]["message"]
        assert client.post("/api/sessions/rig/sensors/livox/accumulate",
                           json={"integration_s": 0}).status_code == 422

        # a LiDAR-camera pair whose cloud is 0.3 s of the Livox added up (the targetless methods' input)
        started = client.post("/api/sessions/rig/lidar-camera/capture", json={
            "camera": "cam", "lidar": "livox", "require_board": False, "integration_s": 0.3})
        assert started.status_code == 202, started.text
        job = wait_job(client, started.json()["id"])
        assert job["state"] == "done", job
        cloud = next(c for c in store.get("rig").captures("livox") if c.id == job["summary"]["cloud"])
        assert cloud.meta["integration_s"] == 0.3 and cloud.meta["coverage"] > 0.3 and cloud.meta["frames"] >= 2


def test_the_lidar_step_accumulates_and_draws_the_coverage(store, free_port) -> None:
    session = store.get("rig")
    with in_process_studio(store, session, free_port) as (app, notes):
        panel = app.lidar_step.accumulation
        assert panel.sensor.options == ("livox", "bare")
        before = len(session.captures("livox"))
        empty = to_rgb(coverage_image(None))
        panel.integration.value = 0.3
        panel._accumulate()
        poll(lambda: len(session.captures("livox")) == before + 1 and (
            panel.coverage.image.shape != empty.shape or (panel.coverage.image != empty).mean() > 0.05),
             lambda: f"nothing accumulated: {panel.jobs.text.content} {notes}", 120)
        poll(lambda: notes and notes[-1][0] == "Cloud accumulated", lambda: str(notes), 30)
        assert "% of the field of view" in notes[-1][1]
        panel.sensor.value = "bare"
        panel._accumulate()
        assert notes[-1][0] == "Cannot accumulate" and "no capture device" in notes[-1][1], notes
