"""The servo-scanner rig through the HTTP API: its image + sweep pairs listed with their pan readings, the board's
corners in a sweep (JSON and the drawn image), the pan-axis solve and the corners solve as jobs (202, then the
job's status), the pan-axis result accepted into the rig, and the 4xx JSON of bad input: a board too small in the
intensity image named with its sweep."""

from __future__ import annotations

import math
from collections.abc import Iterator

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.core.transforms import transform_error
from backend.services.demo_servo_scanner import CAMERA_NAME, LIDAR_NAME, SERVO_SCANNER_NAME
from backend.store.session import Session
from tests.conftest import wait_job
from tests.servo_scanner_rig import servo_scanner_sessions, store_far_pair, true_T_camera_lidar, truth

pytestmark = pytest.mark.slow

SWEEP = f"/api/sessions/{SERVO_SCANNER_NAME}/sensors/{LIDAR_NAME}/sweep"
SOLVE_WAIT_S = 120


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    app = create_app(servo_scanner_sessions(tmp_path_factory, "servo_scanner_api"))
    with TestClient(app) as client:
        yield client
    app.state.studio.jobs.shutdown()


def _session(client: TestClient) -> Session:
    return client.app.state.studio.store.get(SERVO_SCANNER_NAME)


def _solved(client: TestClient, route: str, body: dict) -> dict:
    """POST a solve, check its 202 and job status, wait for it; the stored result."""
    response = client.post(f"{SWEEP}/{route}", json=body)
    assert response.status_code == 202, response.text
    assert response.json()["state"] == "running" and response.json()["result_id"] is None
    status = wait_job(client, response.json()["id"], timeout_s=SOLVE_WAIT_S)
    assert status["state"] == "done", status
    return client.get(f"/api/sessions/{SERVO_SCANNER_NAME}/results/{status['result_id']}").json()


def test_pairs_and_the_corners_of_a_sweep(client: TestClient) -> None:
    pairs = client.get(f"{SWEEP}/pairs", params={"camera": CAMERA_NAME})
    assert pairs.status_code == 200, pairs.text
    assert sorted({p["pan_deg"] for p in pairs.json()}) == [-45.0, 0.0, 45.0] and len(pairs.json()) == 14
    sweep = pairs.json()[0]["cloud"]
    found = client.get(f"{SWEEP}/corners/{sweep}")
    assert found.status_code == 200, found.text
    corners = found.json()
    assert len(corners["ids"]) >= 36 and np.shape(corners["points_m"]) == (len(corners["ids"]), 3)
    assert 0.005 < corners["plane_rms_m"] < 0.015  # the Hokuyo's 1 cm range noise
    drawn = client.get(f"{SWEEP}/corners/{sweep}/image")
    assert drawn.status_code == 200 and drawn.headers["content-type"] == "image/png"
    assert cv2.imdecode(np.frombuffer(drawn.content, np.uint8), cv2.IMREAD_COLOR).shape[1] == 480


def test_the_pan_axis_as_a_job_then_accepted(client: TestClient) -> None:
    record = _solved(client, "pan-axis", {"camera": CAMERA_NAME})
    assert (record["method"], record["parent"], record["child"]) == ("pan_axis", CAMERA_NAME, LIDAR_NAME)
    session = _session(client)
    axis = np.array(record["diagnostics"]["pan_axis"]["axis"])
    axis_error_deg = math.degrees(math.acos(min(1.0, float(axis @ truth(session)["pan_axis"]["axis"]))))
    error_m, error_deg = transform_error(np.array(record["T_parent_child"]), true_T_camera_lidar(session))
    assert axis_error_deg < 0.1 and np.linalg.norm(error_m) < 0.01 and np.linalg.norm(error_deg) < 0.3
    assert record["verdict"]["level"] in ("trusted", "check"), record["verdict"]
    accepted = client.post(f"/api/sessions/{SERVO_SCANNER_NAME}/sensors/{LIDAR_NAME}/lidar-camera/accept",
                           json={"result_id": record["id"], "confirm": True})
    assert accepted.status_code == 200, accepted.text
    assert accepted.json()["accepted"][f"{LIDAR_NAME}/T_{CAMERA_NAME}_{LIDAR_NAME}"] == record["id"]


def test_the_corners_method_as_a_job_on_chosen_pairs(client: TestClient) -> None:
    pairs = [p for p in client.get(f"{SWEEP}/pairs", params={"camera": CAMERA_NAME}).json() if p["pan_deg"] == 45.0]
    record = _solved(client, "corners", {"camera": CAMERA_NAME, "pan_deg": 45.0,
                                         "image_ids": [p["image"] for p in pairs[:3]]})
    assert record["method"] == "corners" and record["diagnostics"]["pan_deg"] == 45.0
    assert len(record["diagnostics"]["placements"]) == 3 and len(record["inputs"]) == 3
    assert any("the camera turned to pan +45 deg" in warning for warning in record["warnings"])


def test_bad_input_is_a_4xx_naming_it(client: TestClient) -> None:
    far = store_far_pair(_session(client))
    too_small = client.get(f"{SWEEP}/corners/{far.cloud.id}")
    assert too_small.status_code == 422, too_small.text
    error = too_small.json()["error"]
    assert error["input"] == f"{LIDAR_NAME}:{far.cloud.id}" and "the board" in error["message"]
    # solved from that pair alone: queued (its corners are found in the job), then failed naming it
    response = client.post(f"{SWEEP}/corners", json={"camera": CAMERA_NAME, "image_ids": [far.image.id]})
    assert response.status_code == 202, response.text
    status = wait_job(client, response.json()["id"], timeout_s=SOLVE_WAIT_S)
    assert status["state"] == "failed" and status["error"]["input"] == far.name, status
    assert "not found in any shot" in status["error"]["message"]
    refusals = [
        ("corners", {"camera": CAMERA_NAME, "pan_deg": 30.0}, 422, "pan_deg"),
        ("corners", {"camera": CAMERA_NAME, "pan_deg": "nan"}, 422, "pan_deg"),
        ("corners", {"camera": LIDAR_NAME}, 422, "camera"),
        ("corners", {"camera": "nope"}, 404, "sensor"),
        ("pan-axis", {"camera": CAMERA_NAME, "init": {"xyz_m": [0.0]}}, 422, "init.xyz_m.1"),
    ]
    for route, body, code, named in refusals:
        response = client.post(f"{SWEEP}/{route}", json=body)
        assert response.status_code == code and response.json()["error"]["input"] == named, (route, body,
                                                                                              response.text)
    not_swept = client.post(f"/api/sessions/{SERVO_SCANNER_NAME}/sensors/{CAMERA_NAME}/sweep/pan-axis",
                            json={"camera": CAMERA_NAME})
    assert not_swept.status_code == 422 and "not a swept scanner" in not_swept.json()["error"]["message"]
