"""The depth network through the API on the simulated cell: depth uploads, the guided procedure scripted step by step
(within 10 mm of the truth), the solve job, verification, the map, the pose table, and bad input (a step out of
order, a table missing, empty depth, a wrong file or size, a wrong layout), each a 4xx JSON error that keeps the pose
and every capture.

Captures are rendered with H1's ``CellScene`` at the true poses and uploaded as ``.npy`` depth (m) and amplitude.
"""

from __future__ import annotations

import io
from collections.abc import Iterator

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.core.depth import pose_from_row
from backend.core.depth_cell import PAPER_NODE_POSES, default_cell_layout
from backend.core.transforms import transform_error
from backend.sim.depth_cell import CellScene
from tests.calib.depth.conftest import pose_error, render_captures, typed_pose
from tests.conftest import wait_job

BASE = "/api/sessions/cell/depth-network"
GUIDED_PASSES = 2
"""Passes over the three steps (the paper goes round again: each tilt leaves a little of the other)."""


def npy(image: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, image, allow_pickle=False)
    return buffer.getvalue()


def upload(client: TestClient, node: str, depth: np.ndarray, amplitude: np.ndarray | None = None,
           arrangement: str = "free", tables: str = "", name: str = "depth.npy"):
    files = [("depth", (name, npy(depth) if name.endswith(".npy") else depth.tobytes(), "application/octet-stream"))]
    if amplitude is not None:
        files.append(("amplitude", ("amplitude.npy", npy(amplitude), "application/octet-stream")))
    return client.post(f"{BASE}/nodes/{node}/captures", files=files,
                       data={"arrangement": arrangement, "tables": tables})


def pose(row) -> dict[str, list[float]]:
    """The API's pose of a depth row (X, Y, Z m, RotZ, RotY, RotX deg)."""
    return {"xyz_m": list(row[:3]), "ypr_deg": list(row[3:])}


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    app = create_app(tmp_path_factory.mktemp("depth-api"))
    with TestClient(app) as client:
        assert client.post("/api/sessions", json={"name": "cell"}).status_code == 201
        # sn1 at its typed pose, to calibrate; sn2 at its true pose (calibrated before)
        for node, row in (("sn1", typed_pose("sn1")), ("sn2", list(PAPER_NODE_POSES["sn2"]))):
            response = client.post(f"{BASE}/nodes", json={"name": node, "pose": pose(row)})
            assert response.status_code == 201, response.text
        for arrangement, tables, frame in render_captures("sn1", seed=7):
            response = upload(client, "sn1", frame.depth_m, frame.amplitude, arrangement, ",".join(tables))
            assert response.status_code == 201, response.text
            assert response.json()["meta"]["tables"] == tables
        rng = np.random.default_rng(3)
        for node, arrangement, tables in (("sn1", "free", ""), ("sn2", "behind", "table1,table2,table3")):
            # sn1: the tables cleared away (its crosses all in view); sn2: the user says three tables stand behind
            # each other, but none does
            bare = CellScene(default_cell_layout()).render(pose_from_row(PAPER_NODE_POSES[node]), rng)
            assert upload(client, node, bare.depth_m, bare.amplitude, arrangement, tables).status_code == 201
        yield client
    app.state.studio.jobs.shutdown()


def error(response, status: int) -> dict:
    assert response.status_code == status, response.text
    body = response.json()["error"]
    assert body["message"], body
    return body


@pytest.mark.slow
def test_the_guided_procedure_reaches_10_mm(client: TestClient) -> None:
    assert error(client.post(f"{BASE}/guided/sn1/advise", json={"step": "tables_behind"}), 409)["message"] == (
        "the guided procedure of sn1 has not started: type its measured pose first (step 'initial')")
    state = client.post(f"{BASE}/guided/sn1/start", json={"pose": pose(typed_pose("sn1"))}).json()
    assert (state["step"], state["done"]) == ("tables_behind", ["initial"])
    refused = error(client.post(f"{BASE}/guided/sn1/apply", json={"step": "tables_beside"}), 409)
    assert refused["message"].startswith("step 'tables_beside' comes after 'tables_behind' (RotX before RotY: "
                                         "rotations interact)")
    assert len(client.get(f"{BASE}/guided/sn1").json()["history"]) == 1  # the pose is kept
    advice = client.post(f"{BASE}/guided/sn1/advise", json={"step": "tables_behind"}).json()
    assert list(advice["suggestion"]) == ["RotX", "Z"] and not advice["done"] and "RotX" in advice["why"]
    for _ in range(GUIDED_PASSES):
        for step in ("tables_behind", "tables_beside", "lines"):
            state = client.post(f"{BASE}/guided/sn1/apply", json={"step": step}).json()
            assert step in state["done"], state
    assert state["complete"] and len(state["history"]) == 1 + 3 * GUIDED_PASSES
    trans_m, rot_deg = pose_error(state["T_world_node"], "sn1")
    assert trans_m < 0.010, (trans_m, rot_deg)  # the 10 mm for the guided path
    record = client.post(f"{BASE}/guided/sn1/finish", json={"accept": True, "confirm": True})
    assert record.status_code == 201, record.text
    record = record.json()
    assert (record["kind"], record["method"], record["parent"], record["child"]) == (
        "depth_node", "guided", "world", "sn1")
    least_squares = record["diagnostics"]["least_squares"]
    assert "problem" not in least_squares, least_squares
    # its sigma (from the least-squares solve of the same captures and the offset from it) covers its error
    error_m, error_deg = transform_error(np.array(record["T_parent_child"]), pose_from_row(PAPER_NODE_POSES["sn1"]))
    assert np.all(np.abs(error_m) <= 3 * np.array(record["std"]["trans_m"])), (error_m, record["std"])
    assert np.all(np.abs(error_deg) <= 3 * np.array(record["std"]["rot_deg"])), (error_deg, record["std"])
    assert record["verdict"]["level"] == "trusted", record["verdict"]  # 0.5 mm, 0.006 deg here
    summary = client.get(f"{BASE}/summary").json()
    assert summary["nodes"]["sn1"]["result_id"] == record["id"]
    assert pose_error(summary["nodes"]["sn1"]["T_world_node"], "sn1")[0] < 0.010
    undone = client.post(f"{BASE}/guided/sn1/undo").json()
    assert len(undone["history"]) == 3 * GUIDED_PASSES


def test_the_solve_job_and_accept(client: TestClient) -> None:
    job = client.post(f"{BASE}/nodes/sn1/solve", json={})
    assert job.status_code == 202, job.text
    status = wait_job(client, job.json()["id"], timeout_s=240)
    assert status["state"] == "done", status
    record = client.get(f"/api/sessions/cell/results/{status['result_id']}").json()
    assert (record["kind"], record["method"], record["child"]) == ("depth_node", "constraints", "sn1")
    accepted = client.post(f"{BASE}/nodes/sn1/accept", json={"result_id": record["id"], "confirm": True})
    assert accepted.status_code == 200, accepted.text
    trans_m, rot_deg = pose_error(client.get(f"{BASE}/summary").json()["nodes"]["sn1"]["T_world_node"], "sn1")
    assert trans_m < 0.005 and rot_deg < 0.05, (trans_m, rot_deg)
    assert error(client.post(f"{BASE}/nodes/sn2/accept", json={"result_id": record["id"]}), 422)["input"] == "result"
    assert error(client.post(f"{BASE}/nodes/sn9/solve", json={}), 404)["input"] == "sensor"
    assert error(client.post(f"{BASE}/solve", json={"nodes": ["sn1", "sn9"]}), 404)["input"] == "sensor"
    network = wait_job(client, client.post(f"{BASE}/solve", json={"nodes": ["sn2"]}).json()["id"], timeout_s=240)
    assert network["state"] == "done" and set(network["summary"]) == {"results", "accepted", "icp", "problems"}
    assert "sn2" in network["summary"]["results"] or network["summary"]["problems"][0].startswith("sn2: ")


def test_verification_map_and_tables(client: TestClient) -> None:
    targets = client.get(f"{BASE}/targets").json()
    assert len(targets) >= 3 and {v["node"] for t in targets for v in t["views"]} == {"sn1", "sn2"}, targets
    a, b = targets[0], targets[1]
    truth = default_cell_layout()
    measured = float(np.linalg.norm(np.subtract(truth.cross(a["name"]).position_m, truth.cross(b["name"]).position_m)))
    row = client.post(f"{BASE}/verification", json={"a": a, "b": b, "measured_m": measured})
    assert row.status_code == 201, row.text
    assert abs(row.json()["error_m"]) < 0.010
    assert [r["a"] for r in client.get(f"{BASE}/verification").json()] == [a["name"]]
    assert error(client.post(f"{BASE}/verification", json={"a": a, "b": b, "measured_m": -1}), 422)
    assert client.delete(f"{BASE}/verification", params={"index": 0}).status_code == 204
    assert error(client.delete(f"{BASE}/verification", params={"index": 0}), 404)["input"] == "index"
    picked = client.post(f"{BASE}/pick", json={"origin_m": [a["point_m"][0], a["point_m"][1], 3.0],
                                               "direction": [0, 0, -1]}).json()
    assert picked["name"] == a["name"] and picked["kind"] == "cross"

    voxels = client.get(f"{BASE}/voxel-map", params={"voxel_m": 0.1, "max_voxels": 100}).json()
    assert voxels["truncated"] and len(voxels["centres_m"]) == len(voxels["counts"]) == 100
    assert voxels["nodes"] == ["sn1", "sn2"] and voxels["n_voxels"] > 100
    assert error(client.get(f"{BASE}/voxel-map", params={"voxel_m": 0}), 422)

    text = client.get(f"{BASE}/pose-table").text
    assert text.splitlines()[1].startswith("sn1") and text.splitlines()[2].startswith("sn2")
    export = client.get("/api/sessions/cell/export/pose-table")
    assert export.status_code == 200 and export.text.startswith("node,X_m,Y_m,Z_m,RotZ_deg,RotY_deg,RotX_deg")


def test_bad_input_is_a_4xx_and_keeps_everything(client: TestClient) -> None:
    captures = len(client.get(f"{BASE}/nodes/sn2/captures").json())
    state = client.post(f"{BASE}/guided/sn2/start", json={"pose": pose(typed_pose("sn2"))}).json()
    missing = error(client.post(f"{BASE}/guided/sn2/apply", json={"step": "tables_behind"}), 422)
    assert "table" in missing["message"] and "the pose is kept" in missing["message"]
    assert client.get(f"{BASE}/guided/sn2").json()["history"] == state["history"]
    assert error(client.post(f"{BASE}/guided/sn2/apply", json={"step": "sideways"}), 422)["input"] == "step"

    assert "no return within" in error(upload(client, "sn2", np.zeros((424, 512), np.float32)), 422)["message"]
    assert "expected 512x424" in error(upload(client, "sn2", np.ones((10, 10), np.float32)), 422)["message"]
    assert error(upload(client, "sn2", np.ones((424, 512), np.float32), name="depth.txt"), 422)["input"] == \
        "depth.txt"
    assert error(upload(client, "sn2", np.ones((424, 512), np.float32) * 3, tables="table9"), 422)["input"] == "table"
    assert error(upload(client, "sn2", np.ones((424, 512), np.float32) * 3, arrangement="stacked"), 422)
    assert len(client.get(f"{BASE}/nodes/sn2/captures").json()) == captures

    layout = client.get(f"{BASE}/layout").json()
    layout["lines"][0]["axis"] = "z"
    assert error(client.put(f"{BASE}/layout", json=layout), 422)["input"].endswith("axis")
    assert client.get(f"{BASE}/layout").json()["lines"][0]["axis"] == "x"
    assert error(client.post(f"{BASE}/nodes/sn1/capture-live", json={}), 409)["input"] == "node_network"
    assert "listen for nodes" in error(client.get(f"{BASE}/presence"), 409)["message"]
    assert error(client.get(f"{BASE}/network"), 409)["input"] == "node_network"
    assert error(client.post(f"{BASE}/nodes/sn1/confirm-device"), 409)["input"] == "node_network"


def test_png_and_integer_uploads_are_millimetres(client: TestClient) -> None:
    frame = render_captures("sn2", seed=5)[0][2]
    millimetres = np.round(frame.depth_m * 1000).astype(np.uint16)
    ok, png = cv2.imencode(".png", millimetres)
    assert ok
    for name, data in (("depth.png", png.tobytes()), ("depth.npy", npy(millimetres))):
        response = client.post(f"{BASE}/nodes/sn2/captures", files=[("depth", (name, data, "image/png"))])
        assert response.status_code == 201, response.text
        assert response.json()["meta"]["amplitude_missing"] is True
    session = client.app.state.studio.store.get("cell")
    depth, _ = session.depth_capture("sn2", response.json()["id"])
    assert np.abs(depth - frame.depth_m).max() <= 0.0005 + 1e-6  # rounded to the millimetre
    ok, gray = cv2.imencode(".png", (frame.depth_m * 20).astype(np.uint8))
    files = [("depth", ("d.png", gray.tobytes(), "image/png"))]
    refused = error(client.post(f"{BASE}/nodes/sn2/captures", files=files), 422)
    assert "expected a 16-bit PNG of millimetres" in refused["message"]
