"""The LiDAR-to-camera API: pairs uploaded and listed, a solve as a job, overlays and result files, a hand-set
transform, acceptance, and the 4xx JSON of what cannot be done."""

from __future__ import annotations

import io

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.core.boards import BoardSpec
from backend.core.transforms import invert, to_xyz_ypr
from backend.sim.board_renderer import render_board_image
from backend.sim.demo_rig import DEMO_BOARD, demo_rig
from backend.sim.lidar_scene import LidarScene, moving_board_poses
from tests.conftest import wait_job

RIG = demo_rig()
T_TRUE = RIG.T_a_b("cam_front", "lidar_front")


@pytest.fixture
def client(tmp_path):
    app = create_app(tmp_path)
    with TestClient(app) as client:
        app.state.studio.store.create("l2c", rig=demo_rig(), board=DEMO_BOARD)
        yield client


def _pair_files(i: int, T_base_board: np.ndarray, rng: np.random.Generator) -> dict:
    camera = RIG.get("cam_front").intrinsics
    T_camera_board = invert(RIG.T_root_frame("cam_front")) @ T_base_board
    image = render_board_image(camera, BoardSpec.parse(DEMO_BOARD), T_camera_board, rng)
    scan = LidarScene(board_pose=T_base_board).scan_3d(RIG.T_root_frame("lidar_front"), beams=64, rng=rng)
    cloud = io.BytesIO()
    np.save(cloud, scan.points)
    return {"image": (f"frame{i}.png", cv2.imencode(".png", image)[1].tobytes(), "image/png"),
            "cloud": (f"frame{i}.npy", cloud.getvalue(), "application/octet-stream")}


@pytest.mark.slow
def test_pairs_solve_overlay_and_accept(client):
    rng = np.random.default_rng(3)
    for i, T_base_board in enumerate(moving_board_poses(6, seed=2)):
        response = client.post("/api/sessions/l2c/lidar-camera/pairs", data={"camera": "cam_front",
                               "lidar": "lidar_front"}, files=_pair_files(i, T_base_board, rng))
        assert response.status_code == 201, response.text
        assert response.json()["board_found"]
    listed = client.get("/api/sessions/l2c/lidar-camera/pairs", params={"camera": "cam_front", "lidar": "lidar_front"})
    assert listed.status_code == 200 and len(listed.json()) == 6

    xyz, ypr = to_xyz_ypr(T_TRUE)
    init = {"init": {"xyz_m": (xyz + [0.06, -0.05, 0.06]).tolist(),  # 10 cm and 5 deg off
                     "ypr_deg": (np.degrees(ypr) + [3, -3, 2.5]).tolist()}}
    response = client.post("/api/sessions/l2c/lidar-camera/solve",
                           json={"camera": "cam_front", "lidar": "lidar_front", "method": "target", **init})
    assert response.status_code == 202, response.text
    status = wait_job(client, response.json()["id"], timeout_s=120)
    assert status["state"] == "done", status
    result_id = status["result_id"]
    record = client.get(f"/api/sessions/l2c/results/{result_id}").json()
    assert (record["kind"], record["method"], record["parent"], record["child"]) == (
        "lidar_camera", "target", "cam_front", "lidar_front")
    error = invert(T_TRUE) @ np.array(record["T_parent_child"])
    assert np.linalg.norm(error[:3, 3]) < 0.01, record["std"]
    assert record["files"] == ["overlay_after.jpg", "overlay_before.jpg"]

    image_id = listed.json()[0]["image"]
    overlay = client.get(f"/api/sessions/l2c/lidar-camera/overlay/{image_id}",
                         params={"camera": "cam_front", "lidar": "lidar_front", "result_id": result_id})
    assert overlay.status_code == 200 and overlay.headers["content-type"] == "image/jpeg"
    assert cv2.imdecode(np.frombuffer(overlay.content, np.uint8), cv2.IMREAD_COLOR).shape == (720, 1280, 3)
    after = client.get(f"/api/sessions/l2c/results/{result_id}/files/overlay_after.jpg")
    assert after.status_code == 200 and after.content[:2] == b"\xff\xd8"
    escape = client.get(f"/api/sessions/l2c/results/{result_id}/files/..%2Fsession.json")
    assert escape.status_code in (404, 422), escape.text

    assert record["verdict"]["level"] in ("trusted", "check"), record["verdict"]
    accepted = client.post("/api/sessions/l2c/sensors/lidar_front/lidar-camera/accept",
                           json={"result_id": result_id, "confirm": record["verdict"]["level"] == "check"})
    assert accepted.status_code == 200, accepted.text
    assert accepted.json()["accepted"]["lidar_front/T_cam_front_lidar_front"] == result_id


def test_hand_set_transform_and_errors(client):
    xyz, ypr = to_xyz_ypr(T_TRUE)
    response = client.post("/api/sessions/l2c/lidar-camera/manual", json={
        "camera": "cam_front", "lidar": "lidar_front",
        "pose": {"xyz_m": xyz.tolist(), "ypr_deg": np.degrees(ypr).tolist()}})
    assert response.status_code == 201, response.text
    result_id = response.json()["result_id"]
    record = client.get(f"/api/sessions/l2c/results/{result_id}").json()
    np.testing.assert_allclose(record["T_parent_child"], T_TRUE, atol=1e-9)
    assert (record["method"], record["parent"], record["child"]) == ("manual", "cam_front", "lidar_front")
    assert record["covariance"] == [[None] * 6] * 6  # nothing measured it
    assert record["verdict"] == {"level": "check", "reasons": ["set by hand: no uncertainty, no cross-check"]}
    url = "/api/sessions/l2c/sensors/{}/lidar-camera/accept"
    other = client.post(url.format("lidar_top"), json={"result_id": result_id, "confirm": True})
    assert other.status_code == 422 and "belongs to lidar_front, not lidar_top" in other.json()["error"]["message"]
    unconfirmed = client.post(url.format("lidar_front"), json={"result_id": result_id})
    assert unconfirmed.status_code == 409 and unconfirmed.json()["error"]["input"] == "confirm", unconfirmed.text
    accepted = client.post(url.format("lidar_front"), json={"result_id": result_id, "confirm": True})
    assert accepted.status_code == 200, accepted.text
    assert accepted.json()["accepted"]["lidar_front/T_cam_front_lidar_front"] == result_id

    files = {"image": ("frame.png", b"garbage", "image/png"), "cloud": ("c.npy", b"garbage", "application/x")}
    bad = client.post("/api/sessions/l2c/lidar-camera/pairs", data={"camera": "cam_front", "lidar": "lidar_front"},
                      files=files)
    assert bad.status_code == 422 and bad.json()["error"]["input"] == "frame.png", bad.text
    no_pairs = client.post("/api/sessions/l2c/lidar-camera/solve", json={"camera": "cam_front", "lidar": "lidar_top"})
    assert no_pairs.status_code == 422
    assert "no image+cloud pairs of cam_front and lidar_top yet" in no_pairs.json()["error"]["message"]
    method = client.post("/api/sessions/l2c/lidar-camera/solve",
                         json={"camera": "cam_front", "lidar": "lidar_top", "method": "icp"})
    assert method.status_code == 422 and method.json()["error"]["input"] == "method"
    not_a_camera = client.post("/api/sessions/l2c/lidar-camera/capture", json={"camera": "lidar_top",
                                                                             "lidar": "lidar_front"})
    assert not_a_camera.status_code == 422 and "not a camera" in not_a_camera.json()["error"]["message"]


def test_a_rejected_pair_upload_stores_nothing(client):
    # A camera without intrinsics: an image's size is checked against the camera's earlier captures, and a pair
    # refused for it keeps neither its image nor its cloud.
    rig = demo_rig()
    rig.get("cam_front").intrinsics = None
    client.app.state.studio.store.create("bare", rig=rig, board=DEMO_BOARD)
    url, form = "/api/sessions/bare/lidar-camera/pairs", {"camera": "cam_front", "lidar": "lidar_front"}
    files = _pair_files(0, moving_board_poses(2)[1], np.random.default_rng(3))
    assert client.post(url, data=form, files=files).status_code == 201

    small = cv2.imencode(".png", np.zeros((480, 640), np.uint8))[1].tobytes()
    refused = client.post(url, data=form, files={**files, "image": ("small.png", small, "image/png")})
    assert refused.status_code == 422, refused.text
    assert refused.json()["error"]["input"] == "small.png"
    assert "640x480 px but earlier captures of cam_front are 1280x720 px" in refused.json()["error"]["message"]
    for sensor in ("cam_front", "lidar_front"):
        captures = client.get(f"/api/sessions/bare/sensors/{sensor}/captures").json()
        assert [c["id"] for c in captures] == ["00001"], (sensor, captures)
    assert len(client.get(url, params=form).json()) == 1
