"""Devices checked as sensors are added (issue 20): each driver's device is opened first, and one that does not
answer is a 422 naming ``device`` and why; a rig can still be defined before its hardware is plugged in, as an
explicit *add as not connected*, and such a sensor is listed so until its device answers."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.devices.base import Sample
from backend.services.sensor_stream import SensorStream

S = "/api/sessions/s"


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    app = create_app(tmp_path / "sessions")
    with TestClient(app) as c:
        assert c.post("/api/sessions", json={"name": "s"}).status_code == 201
        yield c
    app.state.studio.jobs.shutdown()


def frame(client: TestClient, name: str) -> dict:
    return next(f for f in client.get(f"{S}/rig").json()["frames"] if f["name"] == name)


@pytest.mark.parametrize(("device", "reason"), [
    ({"driver": "uvc", "device": "/dev/video97"}, "/dev/video97"),
    ({"driver": "uvc", "device": 0}, "camera"),
    ({"driver": "folder", "path": "/no/such/folder"}, "/no/such/folder"),
    ({"driver": "ydlidar", "port": "/dev/ttyUSB97"}, "/dev/ttyUSB97"),
    ({"driver": "cloud_files", "path": "/no/such/clouds"}, "/no/such/clouds"),
    ({"driver": "uvc", "colour": 1}, "colour"),
    ({"driver": "nope"}, "unknown driver 'nope'"),
])
def test_a_device_that_does_not_answer_is_refused_by_name(client, device, reason):
    response = client.post(f"{S}/sensors", json={"name": "cam", "kind": "camera", "device": device})
    assert response.status_code == 422, response.text
    error = response.json()["error"]
    assert error["input"] == "device" and reason in error["message"], error
    assert client.get(S).json()["sensors"] == []


def test_a_busy_udp_port_is_refused(client):
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        port = taken.getsockname()[1]
        response = client.post(f"{S}/sensors", json={"name": "velo", "kind": "lidar3d", "device": {
            "driver": "velodyne", "host": "127.0.0.1", "port": port}})
    assert response.status_code == 422 and response.json()["error"]["input"] == "device", response.text
    assert str(port) in response.json()["error"]["message"]


def test_a_sensor_added_as_not_connected_is_listed_so_until_its_device_answers(client):
    camera = {"driver": "simulated", "camera": "cam_front", "seed": 0}
    assert client.post(f"{S}/sensors", json={"name": "cam", "device": camera}).status_code == 201
    assert frame(client, "cam")["not_connected"] is False  # opened when added
    absent = {"driver": "uvc", "device": "/dev/video97"}
    assert client.post(f"{S}/sensors", json={"name": "cam2", "device": absent, "connected": False}).status_code == 201
    assert frame(client, "cam2")["not_connected"] is True
    bad = client.post(f"{S}/sensors", json={"name": "cam3", "device": {"driver": "nope"}, "connected": False})
    assert bad.status_code == 422 and bad.json()["error"]["input"] == "device"  # settings are still checked

    # the device is plugged in (here: set to a simulated one) and a stream opens it
    session = client.app.state.studio.store.get("s")
    session.set_device("cam2", camera)
    opened = threading.Event()

    class OneFrame(SensorStream):
        kept_phrase = "capture(s) taken"

        def handle(self, sample: Sample) -> None:
            opened.set()
            self._stop.set()

    stream = OneFrame(session, "cam2", lambda message, error: None, max_hz=0)
    stream.start()
    assert opened.wait(60)
    stream.stop()
    assert frame(client, "cam2")["not_connected"] is False
