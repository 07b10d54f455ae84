"""Recording two live sensors together and lining their clocks up, through the API, on the simulated demo rig.

The simulated person carries the yard's board without stopping (``move_simulated_board(..., "carried")``); the
demo's ``lidar_top`` stamps its scans :data:`DEMO_LIDAR_CLOCK_OFFSET_S` ahead of the cameras. ``POST /recordings``
stores every frame of ``cam_front`` and ``lidar_top`` as one recording, and the time offset measured from that
recording alone finds the LiDAR's clock (the session's other captures, of the board held still, stay out of it).
"""

from __future__ import annotations

import shutil

import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.core.errors import InputError
from backend.core.rig import Frame
from backend.services import motion_recording
from backend.services.demo import CARRY_S, PAIR_BOARD_POSES, PAIR_HOLD_S, move_simulated_board, simulated_board_motion
from backend.sim.demo_rig import DEMO_BOARD, DEMO_LIDAR_CLOCK_OFFSET_S, demo_rig
from backend.store.session import SessionStore
from tests.conftest import wait_job

RECORD_S = 10.0
SESSION = "/api/sessions/clocks"


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    store = SessionStore(tmp_path_factory.mktemp("motion_recording") / "sessions")
    session = store.create("clocks", rig=demo_rig(), board=DEMO_BOARD)
    session.add_sensor(Frame("imu", "base_link", kind="imu"))
    session.add_sensor(Frame("cam_spare", "base_link", kind="camera"))
    session.set_device("lidar_top", session.rig.get("lidar_top").device | {"board_poses": PAIR_BOARD_POSES})
    move_simulated_board(session, "cam_front", "carried")
    return store


@pytest.fixture(scope="module")
def client(store):
    with TestClient(create_app(store.root)) as client:
        yield client


@pytest.fixture(scope="module")
def recorded(client: TestClient) -> dict:
    """One 10 s recording of cam_front and lidar_top (the job's summary)."""
    started = client.post(f"{SESSION}/recordings", json={"sensors": ["cam_front", "lidar_top"], "duration_s": RECORD_S})
    assert started.status_code == 202, started.text
    job = wait_job(client, started.json()["id"])
    assert job["state"] == "done", job
    return job["summary"]


def test_the_carried_board_moves_every_simulated_device_seeing_it(store):
    session = store.get("clocks")
    assert simulated_board_motion(session, "cam_front") == "carried"
    assert session.rig.get("lidar_top").device["board_carry_s"] == CARRY_S  # it sees the yard's board
    assert "board_carry_s" not in session.rig.get("lidar_front").device  # it does not (no board poses)
    move_simulated_board(session, "cam_front", "scene")
    assert simulated_board_motion(session, "cam_front") == "scene"
    assert session.rig.get("lidar_top").device["board_hold_s"] == PAIR_HOLD_S
    assert "board_carry_s" not in session.rig.get("lidar_top").device
    move_simulated_board(session, "cam_front", "carried")


def test_both_sensors_recorded_every_frame_as_one_recording(client: TestClient, store, recorded: dict) -> None:
    session = store.get("clocks")
    assert recorded["duration_s"] == RECORD_S
    assert recorded["stored"]["cam_front"] >= 20 and recorded["stored"]["lidar_top"] >= 20, recorded
    for sensor, rate in recorded["rates_hz"].items():  # captures a second over the duration, at most the cap
        assert 0 < rate <= motion_recording.MAX_HZ * 1.1 and rate * RECORD_S <= recorded["stored"][sensor] + 1
    for sensor in ("cam_front", "lidar_top"):
        tagged = [c for c in session.captures(sensor) if c.meta.get("recording") == recorded["name"]]
        assert len(tagged) == recorded["stored"][sensor]
        assert client.get(f"{SESSION}/sensors/{sensor}/recordings").json() == [recorded["name"]]
    assert all(c.detection is not None for c in session.captures("cam_front"))


def test_the_recording_alone_gives_the_lidars_clock(client: TestClient, recorded: dict) -> None:
    solve = f"{SESSION}/sensors/lidar_top/time-offset"
    started = client.post(solve, json={"reference": "cam_front", "recording": recorded["name"]})
    assert started.status_code == 202, started.text
    job = wait_job(client, started.json()["id"])
    assert job["state"] == "done", job
    found = client.get(solve).json()[-1]
    error_s, sigma_s = found["time_offset_s"] - DEMO_LIDAR_CLOCK_OFFSET_S, found["std"]["time_s"]
    # held to its sigma always, and to 3 ms when the sigma is fit for that: on a loaded machine a 10 s recording
    # keeps fewer frames, and the sigma says so (the step-11 browser test's rule)
    assert abs(error_s) < 3 * sigma_s + 1e-3, found
    verdict = found["verdict"]
    if sigma_s < 2e-3:  # enough frames kept
        assert abs(error_s) < 3e-3 and verdict["level"] in ("trusted", "check"), found
    else:  # a loaded machine kept too few (CI once: 35.9 ms): the verdict says so rather than trust it
        assert verdict["level"] != "trusted" and any("time offset sigma" in r for r in verdict["reasons"]), found


def test_a_recording_that_does_not_hold_both_sensors_is_refused(client: TestClient, recorded: dict) -> None:
    for reference, sensor, recording in (("cam_front", "lidar_top", "rec-19700101-000000"),
                                         ("cam_right", "lidar_top", recorded["name"])):
        answer = client.post(f"{SESSION}/sensors/{sensor}/time-offset",
                             json={"reference": reference, "recording": recording})
        assert answer.status_code == 422, answer.text
        assert answer.json()["error"] == {"message": f"recording {recording!r} holds no captures of {reference}: "
                                          "record both sensors together first, or measure every capture",
                                          "input": "recording"}


@pytest.mark.parametrize(("body", "status", "expected"), [
    ({"sensors": ["cam_front"], "duration_s": 0}, 422, "duration_s"),
    ({"sensors": ["cam_front"], "duration_s": 61}, 422, "duration_s"),
    ({"sensors": [], "duration_s": 5}, 422, "sensors"),
    ({"sensors": ["nope"], "duration_s": 5}, 404, "nope"),
    ({"sensors": ["imu"], "duration_s": 5}, 422, "imu (imu): recordings hold camera, lidar3d, lidar2d sensors"),
    ({"sensors": ["cam_spare"], "duration_s": 5}, 422, "cam_spare has no capture device"),
    ({"sensors": ["cam_front", "cam_front"], "duration_s": 5}, 422, "expected one or more different sensors"),
])
def test_bad_recordings_are_refused_before_anything_is_opened(client: TestClient, body, status, expected) -> None:
    answer = client.post(f"{SESSION}/recordings", json=body)
    assert answer.status_code == status, answer.text
    assert expected in answer.text


def test_a_device_that_fails_ends_the_recording_and_says_so(store) -> None:
    session = store.get("clocks")
    session.set_device("cam_spare", {"driver": "simulated", "camera": "no_such_camera"})
    with pytest.raises(InputError, match=r"recording rec-\S+ stopped: cam_spare: simulated no_such_camera: no "
                                         r"simulated camera named 'no_such_camera'.*the captures it stored are kept"):
        motion_recording.record_motion(session, ["cam_spare"], 5.0)


def test_a_recording_the_disk_cannot_hold_is_refused_before_it_starts(client: TestClient, store, monkeypatch) -> None:
    free = shutil.disk_usage(store.get("clocks").path).free
    needed = 10.0 * motion_recording.MAX_HZ * 2 * motion_recording.BYTES_PER_SAMPLE
    usage = shutil.disk_usage
    monkeypatch.setattr(motion_recording.shutil, "disk_usage", lambda path: usage(path)._replace(free=int(needed) - 1))
    answer = client.post(f"{SESSION}/recordings", json={"sensors": ["cam_front", "lidar_top"], "duration_s": 10})
    assert answer.status_code == 422, answer.text
    assert answer.json()["error"] == {"message": "recording 2 sensor(s) for 10 s may take 0.3 GB but the session's "
                                                 "disk has 0.3 GB free: record for less, or free space first",
                                      "input": "duration_s"}
    assert free > needed  # the real disk would have held it


def test_a_slow_recording_is_named_by_its_sensors():
    slow = motion_recording.Recording("rec-1", {"cam": 20, "lidar": 90}, {"cam": 0}, 10.0, {"cam": 2.0, "lidar": 9.0})
    assert slow.slow() == ["cam"]
