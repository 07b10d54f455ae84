"""A camera's exterior orientation in the wall's frame through the API, on copies of the disaster-response demo
session (:mod:`backend.services.demo_disaster_response`): each wall image posed against the simulator's truth
through the camera's accepted photogrammetric intrinsics and kept in the history (never accepted into the rig);
the test field beside a checkerboard, with an uploaded wall image the board is not in; and the bad inputs (no test
field, no intrinsics, an unknown capture, an image of another size or without the wall) refused with a 4xx naming
them, nothing kept; and views of another target than the board now (a board changed, a survey replaced) kept but
not solved with."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.core.test_field import TestField
from backend.core.transforms import invert, transform_error
from backend.services.demo_disaster_response import DISASTER_RESPONSE_NAME
from backend.sim.disaster_response import CAMERA
from backend.sim.marker_targets import disaster_response_camera, field_views, render_test_field_image
from tests.conftest import disaster_response_template, fresh_demo

SESSION = f"/api/sessions/{DISASTER_RESPONSE_NAME}"
EXTERIOR = f"{SESSION}/sensors/{CAMERA}/exterior"
FIELD = "testfield:DICT_4X4_50:0.15:survey.csv"
TOLERANCE_M, TOLERANCE_DEG = 0.005, 0.1
"""How close a pose through the solved (not the true) intrinsics must come to the truth: 5 mm, 0.1 deg."""


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    """The API on a copy of the disaster-response session (built once per run, shared with its other tests)."""
    root = fresh_demo(disaster_response_template(tmp_path_factory), tmp_path_factory.mktemp("exterior") / "sessions")
    with TestClient(create_app(root)) as client:
        yield client


def _wall_captures(client: TestClient) -> dict[int, str]:
    """View number -> capture id of the session's wall images (``wall_NN.png``)."""
    captures = client.get(f"{SESSION}/sensors/{CAMERA}/captures").json()
    return {int(c["source"][5:7]): c["id"] for c in captures if (c["source"] or "").startswith("wall_")}


def _png(image: np.ndarray) -> bytes:
    return cv2.imencode(".png", image)[1].tobytes()


def _assert_near_truth(pose: dict, T_camera_wall_true: np.ndarray) -> None:
    """Within the tolerance, and within 3 sigma: the accepted solve's own sigma is carried into the pose's."""
    trans_m, rot_deg = transform_error(np.array(pose["T_wall_camera"]), invert(T_camera_wall_true))
    assert np.linalg.norm(trans_m) < TOLERANCE_M and np.linalg.norm(rot_deg) < TOLERANCE_DEG, (trans_m, rot_deg)
    assert np.all(np.abs(trans_m) < 3 * np.array(pose["std"]["trans_m"])), (trans_m, pose["std"])
    assert np.all(np.abs(rot_deg) < 3 * np.array(pose["std"]["rot_deg"])), (rot_deg, pose["std"])
    assert any("sigma (r0001) is carried into the pose" in reason for reason in pose["verdict"]["reasons"])


def test_each_wall_image_is_posed_near_the_truth_and_kept(client: TestClient):
    views = field_views()
    captures = _wall_captures(client)
    assert sorted(captures) == list(range(len(views)))
    result_ids = []
    for k, capture_id in captures.items():
        response = client.post(EXTERIOR, json={"capture_id": capture_id})
        assert response.status_code == 201, response.text
        pose = response.json()
        _assert_near_truth(pose, views[k])
        eo = pose["exterior_orientation"]
        assert np.allclose([eo["X0_m"], eo["Y0_m"], eo["Z0_m"]], np.array(pose["T_wall_camera"])[:3, 3])
        assert pose["residuals"]["markers_used"] >= 6 and pose["verdict"]["level"] in ("trusted", "check")
        result_ids.append(pose["result_id"])
    stored = client.get(EXTERIOR).json()
    assert [r["id"] for r in stored][-len(result_ids):] == result_ids
    record = stored[-1]
    assert (record["kind"], record["parent"], record["child"]) == ("test_field", "wall", CAMERA)
    assert record["settings"]["intrinsics"] == client.get(SESSION).json()["accepted"][f"{CAMERA}/intrinsics"]
    response = client.post(f"{SESSION}/accept", json={"result_id": record["id"], "confirm": True})
    assert response.status_code == 422 and "cannot be accepted" in response.json()["error"]["message"]


def test_an_unknown_capture_is_a_404_naming_it(client: TestClient):
    response = client.post(EXTERIOR, json={"capture_id": "c9999"})
    assert response.status_code == 404, response.text
    assert response.json()["error"]["input"] == "capture_id" and "c9999" in response.json()["error"]["message"]


@pytest.fixture
def beside(client: TestClient, tmp_path_factory) -> TestClient:
    """A copy of the session whose board is a checkerboard and whose test field stands beside it."""
    root = fresh_demo(disaster_response_template(tmp_path_factory), tmp_path_factory.mktemp("beside") / "sessions")
    with TestClient(create_app(root)) as beside:
        assert beside.put(f"{SESSION}/board", json={"board": "checkerboard:9x6:0.025"}).status_code == 200
        yield beside


def test_a_test_field_beside_a_board_poses_an_uploaded_wall_image(beside: TestClient):
    response = beside.post(EXTERIOR, json={"capture_id": _wall_captures(beside)[0]})
    assert response.status_code == 422 and response.json()["error"]["input"] == "test_field", response.text
    response = beside.put(f"{SESSION}/test-field", json={"test_field": FIELD})
    assert response.status_code == 200 and response.json()["test_field"] == FIELD
    assert response.json()["board"] == "checkerboard:9x6:0.025"

    session = beside.app.state.studio.store.get(DISASTER_RESPONSE_NAME)
    field = TestField.parse(session.test_field, session.path)
    T_camera_wall = field_views(seed=7)[3]
    image = render_test_field_image(disaster_response_camera(), field, T_camera_wall, np.random.default_rng(7))
    before = beside.get(f"{SESSION}/sensors/{CAMERA}/captures").json()
    response = beside.post(f"{EXTERIOR}/images", files={"file": ("../../wall_new.png", _png(image), "image/png")})
    assert response.status_code == 201, response.text
    pose = response.json()
    _assert_near_truth(pose, T_camera_wall)
    captures = beside.get(f"{SESSION}/sensors/{CAMERA}/captures").json()
    assert len(captures) == len(before) + 1
    kept = captures[-1]
    assert (kept["id"], kept["source"], kept["board_found"]) == (pose["capture_id"], "wall_new.png", False)
    assert kept["meta"] == {"wall_view": True}  # never one of the lens's views


@pytest.mark.parametrize(("image", "says"), [
    (np.full((1024, 1280), 128, np.uint8), "0 surveyed marker(s) of DICT_4X4_50 found"),
    (np.full((480, 640), 128, np.uint8), "is 640x480 px but camera's intrinsics"),
])
def test_an_image_that_cannot_be_posed_is_refused_and_not_kept(client: TestClient, image: np.ndarray, says: str):
    before = client.get(f"{SESSION}/sensors/{CAMERA}/captures").json()
    response = client.post(f"{EXTERIOR}/images", files={"file": ("grey.png", _png(image), "image/png")})
    assert response.status_code == 422 and says in response.json()["error"]["message"], response.text
    assert response.json()["error"]["input"] == "grey.png"
    assert client.get(f"{SESSION}/sensors/{CAMERA}/captures").json() == before


def test_a_camera_without_intrinsics_or_a_session_without_a_field_is_told_what_is_missing(client: TestClient):
    assert client.post("/api/sessions", json={"name": "bare"}).status_code == 201
    assert client.post("/api/sessions/bare/sensors", json={"name": "cam", "kind": "camera"}).status_code == 201
    response = client.post("/api/sessions/bare/sensors/cam/exterior", json={"capture_id": "c0001"})
    assert response.status_code == 422 and response.json()["error"]["input"] == "intrinsics_result", response.text
    assert "has no intrinsics yet" in response.json()["error"]["message"]
    response = client.post(EXTERIOR, json={"capture_id": "c0001", "intrinsics_result": "r9999"})
    assert response.status_code == 404, response.text


@pytest.mark.parametrize(("spec", "says"), [
    ("checkerboard:9x6:0.025", "is not testfield:"),
    ("testfield:DICT_4X4_50:0.15:../survey.csv", "reads the survey the session holds"),
    ("testfield:DICT_9X9_50:0.15:survey.csv", "DICT_9X9_50"),
])
def test_a_bad_test_field_spec_is_refused_naming_it(client: TestClient, spec: str, says: str):
    response = client.put(f"{SESSION}/test-field", json={"test_field": spec})
    error = response.json()["error"]
    assert response.status_code == 422 and says in error["message"] and error["input"] == "test_field", response.text


def test_views_of_another_target_are_kept_but_not_solved_with(beside: TestClient):
    """The wall's views were detected against the test field: with a checkerboard as the board, or the wall's survey
    replaced since (their ids index its rows), they are another target's: named, kept, not used."""
    solve = f"{SESSION}/sensors/{CAMERA}/intrinsics/solve"
    response = beside.post(solve, json={})
    assert response.status_code == 422, response.text
    assert "12 view(s) of another target: testfield:DICT_4X4_50:0.15:survey.csv" in response.json()["error"]["message"]
    walls = list(_wall_captures(beside).values())
    response = beside.post(solve, json={"capture_ids": walls[:3]})
    assert response.status_code == 422 and response.json()["error"]["input"] == "capture_ids", response.text
    assert "show another target than the session's checkerboard:9x6:0.025" in response.json()["error"]["message"]

    assert beside.put(f"{SESSION}/board", json={"board": FIELD}).status_code == 200
    session = beside.app.state.studio.store.get(DISASTER_RESPONSE_NAME)
    surveyed = (session.path / "survey.csv").read_bytes()
    moved = b"\n".join(line + b"1" if line.count(b",") == 3 and line[-1:].isdigit() else line
                       for line in surveyed.splitlines())  # every Z a digit longer: another survey
    assert moved != surveyed
    assert beside.put(f"{SESSION}/survey", files={"file": ("wall.csv", moved, "text/csv")}).status_code == 200
    response = beside.post(solve, json={})
    assert response.status_code == 422, response.text
    assert f"{FIELD} (its survey replaced since)" in response.json()["error"]["message"]

    assert beside.put(f"{SESSION}/survey", files={"file": ("wall.csv", surveyed, "text/csv")}).status_code == 200
    assert beside.post(solve, json={"model": "photogrammetric"}).status_code == 202  # the wall's views again
