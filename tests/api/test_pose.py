"""One pose spelling at the API edge (``pose``/``init`` = ``{"xyz_m", "ypr_deg"}``), the old ones still read."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.core.transforms import from_xyz_ypr


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    with TestClient(create_app(tmp_path_factory.mktemp("pose_sessions"))) as client:
        assert client.post("/api/sessions", json={"name": "poses"}).status_code == 201
        yield client


def frame_T(client: TestClient, name: str) -> np.ndarray:
    frames = client.get("/api/sessions/poses/rig").json()["frames"]
    return np.array(next(frame["T_parent_child"] for frame in frames if frame["name"] == name))


@pytest.mark.parametrize(("name", "body"), [
    ("new", {"pose": {"xyz_m": [0.1, -0.2, 0.3], "ypr_deg": [90, 10, -5]}}),
    ("old", {"xyz_m": [0.1, -0.2, 0.3], "ypr_deg": [90, 10, -5]}),
])
def test_both_spellings_place_the_sensor_alike(client: TestClient, name: str, body: dict) -> None:
    response = client.post("/api/sessions/poses/sensors", json={"name": name, **body})
    assert response.status_code == 201, response.text
    expected = from_xyz_ypr(np.array([0.1, -0.2, 0.3]), np.radians([90, 10, -5]))
    np.testing.assert_allclose(frame_T(client, name), expected, atol=1e-12)


def test_an_old_field_alone_keeps_the_other_at_zero(client: TestClient) -> None:
    response = client.post("/api/sessions/poses/sensors", json={"name": "only_xyz", "xyz_m": [1, 2, 3]})
    assert response.status_code == 201, response.text
    np.testing.assert_allclose(frame_T(client, "only_xyz"), from_xyz_ypr(np.array([1, 2, 3]), np.zeros(3)))


def test_both_spellings_at_once_are_a_422_naming_them(client: TestClient) -> None:
    response = client.post("/api/sessions/poses/sensors", json={
        "name": "twice", "pose": {"xyz_m": [0, 0, 0]}, "xyz_m": [1, 0, 0]})
    assert response.status_code == 422, response.text
    error = response.json()["error"]
    assert "'pose'" in error["message"] and "'xyz_m'" in error["message"] and error["input"] == "body"


def test_a_pose_row_of_five_numbers_is_a_422(client: TestClient) -> None:
    response = client.post("/api/sessions/poses/depth-network/nodes", json={"name": "sn1",
                                                                           "pose_row": [1, 2, 3, 4, 5]})
    assert response.status_code == 422, response.text
    assert "six numbers" in response.json()["error"]["message"]


def test_the_openapi_page_marks_the_old_spellings_deprecated(client: TestClient) -> None:
    schemas = client.get("/openapi.json").json()["components"]["schemas"]
    old = {"SensorCreate": ["xyz_m", "ypr_deg"], "LidarLidarSolveRequest": ["init_xyz_m", "init_ypr_deg"],
           "LidarCameraSolveRequest": ["init_xyz_m", "init_ypr_deg"], "LidarCameraManual": ["xyz_m", "ypr_deg"],
           "DepthNodeCreate": ["pose_row"], "NodeSolveRequest": ["init_pose_row"], "GuidedStart": ["pose_row"]}
    for model, fields in old.items():
        properties = schemas[model]["properties"]
        assert all(properties[field].get("deprecated") is True for field in fields), (model, properties)
        new = "init" if fields[0].startswith("init") else "pose"
        assert new in properties and not properties[new].get("deprecated"), (model, new)
