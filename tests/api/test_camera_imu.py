"""Camera-IMU calibration through the API: an uploaded simulated recording (known extrinsic, 23 ms offset) solved in
the background, kept with its files, accepted as the rig's camera-IMU edge; bad files refused naming them."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.core.rig import Frame, Rig
from backend.core.transforms import transform_error
from backend.sim.camera_imu import BOARD, CAMERA, recording_files, simulate_recording
from backend.store.session import SessionStore
from tests.conftest import wait_job

pytestmark = pytest.mark.slow

SOLVE = "/api/sessions/rig/sensors/imu0/camera-imu"


@pytest.fixture(scope="module")
def recording():
    """19 s: one fit. Under 20 s a recording is too short for the two-halves cross-check (two more fits, 5 s of
    CPU), which ``tests/calib/camera_imu/test_sim.py`` holds to its numbers on 24 s; the route is what this tests."""
    return simulate_recording(duration_s=19.0, offset_s=0.023, seed=3)


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    root = tmp_path_factory.mktemp("camera_imu") / "sessions"
    rig = Rig()
    rig.add(Frame("cam0", "base_link", kind="camera", intrinsics=CAMERA))
    rig.add(Frame("imu0", "base_link", kind="imu"))
    rig.add(Frame("cam1", "base_link", kind="camera"))
    SessionStore(root).create("rig", rig=rig)
    with TestClient(create_app(root)) as client:
        yield client


def _post(client: TestClient, imu: bytes, detections: bytes, camera: str = "cam0", sensor: str = "imu0",
          **fields: str):
    return client.post(SOLVE.replace("imu0", sensor), data={"camera": camera, "board": BOARD, **fields},
                       files={"imu": ("imu.csv", imu, "text/csv"), "detections": ("corners.csv", detections,
                                                                                   "text/csv")})


def test_a_recording_is_solved_kept_and_accepted(client: TestClient, recording) -> None:
    """With the ``scale-misalignment`` IMU model asked for: the ideal simulated IMU's scale and misalignment come
    back as identity, and the ``calibrated`` model is the cross-check."""
    imu, detections = recording_files(recording)
    started = _post(client, imu, detections, imu_model="scale-misalignment")
    assert started.status_code == 202, started.text
    job = wait_job(client, started.json()["id"], timeout_s=600)
    assert job["state"] == "done", job
    result_id = job["result_id"]
    listed = client.get(SOLVE).json()
    assert [r["result_id"] for r in listed] == [result_id] and listed[0]["camera"] == "cam0"
    assert abs(listed[0]["time_offset_s"] - 0.023) < 1e-3, listed[0]["time_offset_s"]
    assert listed[0]["imu_model"] == "scale-misalignment"
    intrinsics = listed[0]["imu_intrinsics"]
    assert np.allclose(intrinsics["accel_M"], np.eye(3), atol=5e-3), intrinsics
    assert np.allclose(intrinsics["gyro_M"], np.eye(3), atol=5e-3), intrinsics
    assert any(r.startswith("IMU model: fitted with the calibrated model instead") for r in
               listed[0]["verdict"]["reasons"]), listed[0]["verdict"]
    record = client.get(f"/api/sessions/rig/results/{result_id}").json()
    assert (record["kind"], record["parent"], record["child"]) == ("camera_imu", "cam0", "imu0")
    assert sorted(record["files"]) == ["detections.csv", "imu.csv"]
    trans_m, rot_deg = transform_error(np.array(record["T_parent_child"]), recording.T_cam_imu)
    assert np.linalg.norm(trans_m) < 2e-3 and np.linalg.norm(rot_deg) < 0.1, (trans_m, rot_deg)

    accepted = client.post("/api/sessions/rig/accept", json={"result_id": result_id, "confirm": True})
    assert accepted.status_code == 200, accepted.text
    session = client.get("/api/sessions/rig").json()
    assert session["accepted"]["imu0/T_cam0_imu0"] == result_id, session["accepted"]
    frames = {f["name"]: f for f in client.get("/api/sessions/rig/rig").json()["frames"]}
    assert frames["imu0"]["clock_offset_s"] == pytest.approx(listed[0]["time_offset_s"], abs=1e-12)  # t_imu = t_cam + o


def test_bad_files_and_sensors_are_refused_naming_them(client: TestClient, recording) -> None:
    imu, detections = recording_files(recording)
    lines = imu.decode().splitlines()
    lines[50], lines[51] = lines[51], lines[50]
    backwards = _post(client, ("\n".join(lines) + "\n").encode(), detections)
    assert backwards.status_code == 422, backwards.text
    assert backwards.json()["error"]["input"] == "imu.csv"
    assert "time stamps run backwards or repeat at sample 51" in backwards.json()["error"]["message"]
    other_columns = _post(client, imu, b"time,u,v\n1,2,3\n")
    assert other_columns.status_code == 422 and other_columns.json()["error"]["input"] == "corners.csv"
    not_an_imu = _post(client, imu, detections, sensor="cam0")
    assert not_an_imu.status_code == 404 and "is not an IMU of the rig" in not_an_imu.json()["error"]["message"]
    unknown_model = _post(client, imu, detections, imu_model="scale-misalignment-size-effect")
    assert unknown_model.status_code == 422 and unknown_model.json()["error"]["input"] == "imu_model", (
        unknown_model.text)
    assert "'calibrated' or 'scale-misalignment'" in unknown_model.json()["error"]["message"]
    no_lens = _post(client, imu, detections, camera="cam1")
    assert no_lens.status_code == 422 and "cam1 has no intrinsics yet" in no_lens.json()["error"]["message"]
    assert len(client.get(SOLVE).json()) <= 1  # nothing was kept from the refused uploads
