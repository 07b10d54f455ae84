"""LiDAR endpoints through the real app: cloud uploads, the LiDAR-to-LiDAR job, accept, errors."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.core.transforms import to_xyz_ypr
from tests.conftest import wait_job

PAIR = "opencalib_lidar2lidar_pair"
REFERENCE_T_QT_P64 = np.array([[0.504271, -0.718711, -0.457892, -1.87468], [0.604509, 0.67629, -0.394462, -1.86523],
                               [0.598991, -0.0777196, 0.783179, -0.527022], [0, 0, 0, 1]])
"""From the data set's README (its rotation is scaled by about 0.989; see tests/calib/lidar_lidar/test_gicp.py)."""


@pytest.fixture
def client(tmp_path):
    with TestClient(create_app(tmp_path)) as client:
        client.post("/api/sessions", json={"name": "car"})
        for name in ("p64", "qt"):
            client.post("/api/sessions/car/sensors", json={"name": name, "kind": "lidar3d"})
        yield client


@pytest.mark.slow
def test_real_pair_through_the_api(client, stereo_chessboard):
    data = stereo_chessboard.parent / PAIR
    for sensor in ("p64", "qt"):
        response = client.post(f"/api/sessions/car/sensors/{sensor}/clouds",
                               files=[("files", (f"{sensor}.pcd", (data / f"{sensor}.pcd").read_bytes()))])
        assert response.status_code == 201, response.text
    assert response.json()["added"][0]["n_points"] == 12414

    U, _, Vt = np.linalg.svd(REFERENCE_T_QT_P64[:3, :3])
    xyz, ypr = to_xyz_ypr(np.block([[U @ Vt, REFERENCE_T_QT_P64[:3, 3:]], [np.zeros((1, 3)), np.ones((1, 1))]]))
    job = client.post("/api/sessions/car/lidar-lidar/solve", json={
        "source": "p64", "target": "qt", "init": {"xyz_m": list(xyz), "ypr_deg": list(np.degrees(ypr))}})
    assert job.status_code == 202
    status = wait_job(client, job.json()["id"], timeout_s=120)
    assert status["state"] == "done", status
    record = client.get(f"/api/sessions/car/results/{status['result_id']}").json()
    assert (record["kind"], record["parent"], record["child"]) == ("lidar_lidar", "qt", "p64") and record["converged"]
    assert record["residuals"]["fitness"] > 0.13
    # one real scene: no cross-check
    assert record["verdict"]["level"] == "check" and len(record["diagnostics"]["scenes"]) == 1
    assert client.get("/api/sessions/car/lidar-lidar/pairs", params={"source": "p64", "target": "qt"}).json() == [
        list(p) for p in [record["inputs"][0].split(":")]]
    assert client.get("/api/sessions/car/lidar-lidar/pairing", params={"source": "p64", "target": "qt"}).json() == {
        "pairs": [record["inputs"][0].split(":")], "unpaired": []}  # uploads: no stamps, paired in upload order
    refused = client.post("/api/sessions/car/sensors/p64/lidar-lidar/accept", json={"result_id": status["result_id"]})
    assert refused.status_code == 409 and refused.json()["error"]["input"] == "confirm"
    other = client.post("/api/sessions/car/sensors/qt/lidar-lidar/accept",
                        json={"result_id": status["result_id"], "confirm": True})
    assert other.status_code == 422 and f"result {status['result_id']} belongs to p64, not qt" in \
        other.json()["error"]["message"]
    accepted = client.post("/api/sessions/car/sensors/p64/lidar-lidar/accept",
                           json={"result_id": status["result_id"], "confirm": True})
    assert accepted.status_code == 200
    assert accepted.json()["accepted"] == {"p64/T_qt_p64": status["result_id"]}


def test_errors_name_the_input(client):
    bad = client.post("/api/sessions/car/sensors/p64/clouds", files=[("files", ("scan.pcd", b"VERSION .7\nFIELDS x"))])
    assert bad.status_code == 422 and "scan.pcd" in bad.json()["error"]["message"]
    none = client.post("/api/sessions/car/lidar-lidar/solve", json={"source": "p64", "target": "qt"})
    assert none.status_code == 422 and "no clouds captured for p64" in none.json()["error"]["message"]
    client.post("/api/sessions/car/sensors", json={"name": "cam", "kind": "camera"})
    camera = client.post("/api/sessions/car/lidar-lidar/solve", json={"source": "cam", "target": "qt"})
    assert camera.status_code == 422 and "not a LiDAR" in camera.json()["error"]["message"]
    unknown = client.post("/api/sessions/car/lidar-lidar/solve", json={"source": "nope", "target": "qt"})
    assert unknown.status_code == 404 and unknown.json()["error"]["input"] == "sensor"


@pytest.mark.slow
def test_three_scenes_through_the_api_are_trusted_and_accepted(client, tmp_path):
    """Clouds of three places of the simulated robot: one job over the chosen pairs, per-scene solves, a
    'trusted' verdict (the scenes agree), accepted without a confirmation."""
    import io

    from backend.sim.lidar_scene import LidarScene
    from tests.calib.lidar_lidar.conftest import PLACEMENTS, T_TRUE, perturbed, scan_pair

    scene = LidarScene()
    for i, placement in enumerate(PLACEMENTS):
        for sensor, points in zip(("p64", "qt"), scan_pair(scene, 40 + i, placement), strict=True):
            buffer = io.BytesIO()
            np.save(buffer, points)
            assert client.post(f"/api/sessions/car/sensors/{sensor}/clouds",
                               files=[("files", (f"{sensor}_{i}.npy", buffer.getvalue()))]).status_code == 201
    pairs = client.get("/api/sessions/car/lidar-lidar/pairs", params={"source": "p64", "target": "qt"}).json()
    assert len(pairs) == 3
    xyz, ypr = to_xyz_ypr(perturbed(T_TRUE, 7, 0.10, 5.0))
    job = client.post("/api/sessions/car/lidar-lidar/solve", json={
        "source": "p64", "target": "qt", "pairs": pairs, "init": {"xyz_m": list(xyz),
                                                                  "ypr_deg": list(np.degrees(ypr))}})
    status = wait_job(client, job.json()["id"], timeout_s=120)
    assert status["state"] == "done", status
    record = client.get(f"/api/sessions/car/results/{status['result_id']}").json()
    scenes = record["diagnostics"]["scenes"]
    assert [s["pairs"] for s in scenes] == [[0], [1], [2]] and all(s["agrees"] for s in scenes)
    assert record["verdict"]["level"] == "trusted", record["verdict"]
    assert record["diagnostics"]["scene_spread"]["trans_m"] < 0.01
    error = np.linalg.inv(T_TRUE) @ np.array(record["T_parent_child"])
    assert np.linalg.norm(error[:3, 3]) < 0.003
    accepted = client.post("/api/sessions/car/sensors/p64/lidar-lidar/accept", json={"result_id": status["result_id"]})
    assert accepted.status_code == 200, accepted.text
    assert accepted.json()["accepted"] == {"p64/T_qt_p64": status["result_id"]}
