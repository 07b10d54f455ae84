"""The disaster-response paths through the API on the built demo session
(:mod:`backend.services.demo_disaster_response`): the test field's survey uploaded and set as the board, the
V-target set, the photogrammetric intrinsics solved from the wall's images and the V-target LiDAR-camera solve as
jobs, against the simulator's truth; bad surveys, specs and a board on a session without its survey refused with a
4xx naming them."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.core.transforms import transform_error
from backend.services.demo_disaster_response import DISASTER_RESPONSE_NAME
from backend.sim.disaster_response import CAMERA, LIDAR, T_CAMERA_LIVOX_TRUE
from backend.sim.marker_targets import disaster_response_camera
from tests.conftest import disaster_response_template, fresh_demo, wait_job

SESSION = f"/api/sessions/{DISASTER_RESPONSE_NAME}"


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    """The API on a copy of the disaster-response session, built once per run (the browser test's too)."""
    root = fresh_demo(disaster_response_template(tmp_path_factory), tmp_path_factory.mktemp("api") / "sessions")
    app = create_app(root)
    with TestClient(app) as client:
        yield client


def _solved(client: TestClient, path: str, body: dict) -> dict:
    response = client.post(f"{SESSION}/{path}", json=body)
    assert response.status_code == 202, response.text
    job = wait_job(client, response.json()["id"])
    assert job["state"] == "done", job
    return job


def test_the_session_holds_the_wall_and_the_v_target(client: TestClient):
    info = client.get(SESSION).json()
    assert info["board"] == "testfield:DICT_4X4_50:0.15:survey.csv" and info["survey"]
    assert info["v_target"] == "vtarget:1x0.6:120:3x2:0.15:DICT_4X4_50"


def test_photogrammetric_intrinsics_from_the_wall_as_a_job(client: TestClient):
    job = _solved(client, f"sensors/{CAMERA}/intrinsics/solve",
                  {"model": "photogrammetric", "pixel_size_um": 4.8})
    record = client.get(f"{SESSION}/results/{job['result_id']}").json()
    truth = disaster_response_camera()
    assert record["camera"]["model"] == "photogrammetric" and record["rms_px"] < 0.3
    c = record["photogrammetric"]["parameters"]["c"]
    assert abs(c["value_px"] - truth.K[0, 0]) < 3 * c["sigma_px"]


def test_the_v_target_solve_as_a_job(client: TestClient):
    job = _solved(client, "lidar-camera/solve", {"camera": CAMERA, "lidar": LIDAR, "method": "vtarget"})
    record = client.get(f"{SESSION}/results/{job['result_id']}").json()
    trans_m, rot_deg = transform_error(np.array(record["T_parent_child"]), T_CAMERA_LIVOX_TRUE)
    assert np.abs(trans_m).max() < 0.005 and np.abs(rot_deg).max() < 0.1, (trans_m, rot_deg)
    assert record["method"] == "vtarget" and record["verdict"]["level"] == "trusted", record["verdict"]


@pytest.mark.parametrize(("survey", "says"), [
    (b"0,0,0,0\n1,1,0,0\n2,2,0,0\n1,3,0,0\n4,4,0,0\n5,5,0,0\n", "wall.csv line 4: marker id 1 is surveyed twice"),
    (b"0,0,0\n", "wall.csv line 1: '0,0,0' has 3 fields"),
    (b"\xff\xfe", "wall.csv is not UTF-8 text"),
])
def test_a_bad_survey_is_refused_and_the_session_keeps_its_own(client: TestClient, survey: bytes, says: str):
    before = client.get(SESSION).json()
    response = client.put(f"{SESSION}/survey", files={"file": ("wall.csv", survey, "text/csv")})
    assert response.status_code == 422 and says in response.json()["error"]["message"], response.text
    assert client.get(SESSION).json() == before


def test_a_new_survey_keeps_the_one_it_replaces(client: TestClient, tmp_path):
    session = client.app.state.studio.store.get(DISASTER_RESPONSE_NAME)
    old = (session.path / "survey.csv").read_bytes()
    response = client.put(f"{SESSION}/survey", files={"file": ("../../wall.csv", old, "text/csv")})
    assert response.status_code == 200, response.text
    assert (session.path / "surveys" / "survey-1.csv").read_bytes() == old
    assert not (session.path.parent.parent / "wall.csv").exists()


@pytest.mark.parametrize(("path", "body", "says"), [
    ("board", {"board": "testfield:DICT_4X4_50:0.15:../other/survey.csv"}, "reads the survey the session holds"),
    ("board", {"board": "testfield:DICT_4X4_50:0.15:/etc/passwd"}, "reads the survey the session holds"),
    ("v-target", {"v_target": "vtarget:1.0x0.6:178:3x2:0.15:DICT_4X4_50"}, "from flat (180 deg)"),
])
def test_bad_target_specs_are_refused(client: TestClient, path: str, body: dict, says: str):
    response = client.put(f"{SESSION}/{path}", json=body)
    assert response.status_code == 422 and says in response.json()["error"]["message"], response.text


def test_a_test_field_needs_its_survey_first(client: TestClient):
    response = client.post("/api/sessions", json={"name": "wall2", "board": "testfield:DICT_4X4_50:0.15:survey.csv"})
    assert response.status_code == 422 and "upload the survey" in response.json()["error"]["message"]
    assert client.post("/api/sessions", json={"name": "wall2"}).status_code == 201
    response = client.put("/api/sessions/wall2/board", json={"board": "testfield:DICT_4X4_50:0.15:survey.csv"})
    message = response.json()["error"]["message"]
    assert response.status_code == 422 and "cannot read the survey file survey.csv" in message
