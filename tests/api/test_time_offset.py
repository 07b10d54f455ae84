"""The time offset through the API: a camera's and a LiDAR's captures of a board carried through both views
(simulated, 37 ms apart), measured in the background, accepted as the LiDAR's clock offset, and then applied where
sensors are matched by time: multi-camera sets and the LiDAR-camera pairs say what they assumed."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.calib.lidar_camera.capture import store_pair
from backend.calib.multicam.capture import capture_set
from backend.core.errors import InputError
from backend.devices.base import Sample
from backend.sim.moving_board import CAMERA, simulate_moving_board
from backend.store.session import SessionStore
from tests.conftest import wait_job
from tests.time_offset_session import moving_board_session

SOLVE = "/api/sessions/rig/sensors/lidar/time-offset"


@pytest.fixture(scope="module")
def recording():
    return simulate_moving_board(duration_s=14.0, offset_s=0.037, seed=2, camera_hz=10.0)


@pytest.fixture(scope="module")
def store(tmp_path_factory, recording):
    store = SessionStore(tmp_path_factory.mktemp("time_offset") / "sessions")
    moving_board_session(store, recording)
    return store


@pytest.fixture(scope="module")
def client(store):
    with TestClient(create_app(store.root)) as client:
        yield client


def test_measured_accepted_and_kept_as_the_lidars_clock_offset(client: TestClient, recording) -> None:
    started = client.post(SOLVE, json={"reference": "cam"})
    assert started.status_code == 202, started.text
    job = wait_job(client, started.json()["id"])
    assert job["state"] == "done", job
    listed = client.get(SOLVE).json()
    assert [r["result_id"] for r in listed] == [job["result_id"]]
    found = listed[0]
    assert (found["sensor_a"], found["sensor_b"]) == ("cam", "lidar")
    assert abs(found["time_offset_s"] - recording.offset_s) < 2e-3, found
    assert abs(found["time_offset_s"] - recording.offset_s) < 3 * found["std"]["time_s"], found
    assert found["verdict"]["level"] in ("trusted", "check"), found["verdict"]

    accepted = client.post("/api/sessions/rig/accept", json={"result_id": found["result_id"], "confirm": True})
    assert accepted.status_code == 200, accepted.text
    assert client.get("/api/sessions/rig").json()["accepted"]["lidar/clock_offset"] == found["result_id"]
    frames = {f["name"]: f for f in client.get("/api/sessions/rig/rig").json()["frames"]}
    assert frames["lidar"]["clock_offset_s"] == pytest.approx(found["time_offset_s"], abs=1e-12)
    assert frames["lidar"]["clock_offset_std_s"] == pytest.approx(found["std"]["time_s"], abs=1e-12)
    assert frames["cam"]["clock_offset_s"] == 0.0
    report = client.get("/api/sessions/rig/report")
    assert report.status_code == 200, report.text[:300]
    clock = f"{1e3 * found['time_offset_s']:.2f} ± {1e3 * found['std']['time_s']:.2f}"
    assert clock in report.text and "clock (ms)" in report.text, clock

    plot = client.get(f"{SOLVE}/{found['result_id']}/plot.svg")
    assert plot.status_code == 200 and plot.headers["content-type"] == "image/svg+xml", plot.text[:200]
    assert plot.content.startswith(b"<?xml") and b"<svg" in plot.content[:2000]
    other = client.get(f"/api/sessions/rig/sensors/cam/time-offset/{found['result_id']}/plot.svg")
    assert other.status_code == 422 and "belongs to lidar" in other.json()["error"]["message"], other.text


def test_pairs_and_sets_match_on_the_rigs_clock(client: TestClient) -> None:
    session = client.app.state.studio.store.get("rig")
    session.edit_rig(lambda rig: setattr(rig.get("cam2"), "clock_offset_s", 0.5))
    image = Sample(100.0, image=np.zeros((CAMERA.height, CAMERA.width), np.uint8))
    late = Sample(100.5, image=image.image)  # cam2's clock reads 0.5 s more: the same instant
    made = capture_set(session, ["cam", "cam2"], {"cam": lambda: image, "cam2": lambda: late}, device="test")
    assert {c.meta["multicam_stamp_s"] for c in made.captures.values()} == {100.0}
    assert made.captures["cam2"].meta["clock_offset_s"] == 0.5
    with pytest.raises(InputError, match="cam2"):  # 0.5 s apart on the rig's clock
        capture_set(session, ["cam", "cam2"], {"cam": lambda: image, "cam2": lambda: image}, device="test")

    cloud = Sample(100.0, points=np.ones((10, 3)))
    pair = store_pair(session, "cam", "lidar", image, cloud, device="test", detection=None)
    assert pair.clock_offsets_s == {"cam": 0.0, "lidar": session.rig.get("lidar").clock_offset_s}
    assert pair.clock_offsets_s["lidar"] != 0.0


def test_pairs_that_cannot_be_measured_are_refused_naming_them(client: TestClient) -> None:
    same = client.post(SOLVE, json={"reference": "lidar"})
    assert same.status_code == 422 and "name the camera first" in same.json()["error"]["message"], same.text
    unknown = client.post(SOLVE, json={"reference": "nope"})
    assert unknown.status_code == 404, unknown.text
    wide = client.post(SOLVE, json={"reference": "cam", "max_offset_s": 10})
    assert wide.status_code == 422, wide.text
    empty = client.post("/api/sessions/rig/sensors/cam2/time-offset", json={"reference": "cam"})
    job = wait_job(client, empty.json()["id"])
    assert job["state"] == "failed" and "cam2 has 0 capture(s) with the board" in job["error"]["message"], job
