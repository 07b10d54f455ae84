"""LiDAR-IMU calibration through the API: the LiDAR's captures of the rig turned in the simulated yard and an
uploaded IMU recording (15 ms apart), solved in the background, accepted as the rig's LiDAR-IMU edge and the IMU's
clock offset; bad input refused naming it."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient
from scipy.spatial.transform import Rotation

from backend.api.app import create_app
from backend.core.rig import Frame, Rig
from backend.core.transforms import make_T
from backend.devices.imu_csv import format_imu_csv
from backend.sim.lidar_imu import R_LIDAR_IMU, simulate_lidar_imu
from backend.store.session import SessionStore
from tests.conftest import wait_job

pytestmark = pytest.mark.slow

SOLVE = "/api/sessions/rig/sensors/imu/lidar-imu"
T_MOUNT = make_T(R_LIDAR_IMU @ Rotation.from_euler("xyz", [2.0, -1.5, 2.5], degrees=True).as_matrix(),
                 [0.03, 0.0, -0.05])
"""The IMU's mounting guess under the LiDAR: upside down, as the truth, but 3.5 deg and 5 cm off."""


@pytest.fixture(scope="module")
def recording():
    return simulate_lidar_imu(duration_s=8.0, offset_s=0.015, seed=2)


@pytest.fixture(scope="module")
def client(tmp_path_factory, recording):
    root = tmp_path_factory.mktemp("lidar_imu") / "sessions"
    rig = Rig()
    rig.add(Frame("lidar", "base_link", kind="lidar3d"))
    rig.add(Frame("imu", "lidar", T_MOUNT, kind="imu", mount_sigma=(0.01, 5.0)))
    session = SessionStore(root).create("rig", rig=rig)
    for t_s, points in zip(recording.scan_times_s, recording.scans, strict=True):
        session.add_cloud_capture("lidar", points, None, {"timestamp_s": float(t_s), "device": "sim"})
    with TestClient(create_app(root)) as client:
        yield client


def _post(client: TestClient, imu: bytes, lidar: str = "lidar", sensor: str = "imu"):
    return client.post(SOLVE.replace("/imu/", f"/{sensor}/"), data={"lidar": lidar},
                       files={"imu": ("imu.csv", imu, "text/csv")})


def test_solved_kept_and_accepted_with_the_clock(client: TestClient, recording) -> None:
    started = _post(client, format_imu_csv(recording.imu))
    assert started.status_code == 202, started.text
    job = wait_job(client, started.json()["id"], timeout_s=600)
    assert job["state"] == "done", job
    listed = client.get(SOLVE).json()
    assert [r["result_id"] for r in listed] == [job["result_id"]] and listed[0]["lidar"] == "lidar"
    assert abs(listed[0]["time_offset_s"] - recording.offset_s) < 2e-3, listed[0]["time_offset_s"]
    record = client.get(f"/api/sessions/rig/results/{job['result_id']}").json()
    assert (record["kind"], record["parent"], record["child"]) == ("lidar_imu", "lidar", "imu")
    assert record["files"] == ["imu.csv"] and record["verdict"]["level"] in ("trusted", "check")

    accepted = client.post("/api/sessions/rig/accept", json={"result_id": job["result_id"], "confirm": True})
    assert accepted.status_code == 200, accepted.text
    frames = {f["name"]: f for f in client.get("/api/sessions/rig/rig").json()["frames"]}
    T_lidar_imu = np.array(frames["imu"]["T_parent_child"])
    off_deg = np.degrees(Rotation.from_matrix(T_lidar_imu[:3, :3].T @ recording.R_lidar_imu).magnitude())
    assert off_deg < 0.2, off_deg  # the rotation is the result's
    assert np.linalg.norm(T_lidar_imu[:3, 3] - recording.t_lidar_imu_m) < 6e-3, T_lidar_imu[:3, 3]  # not the guess
    assert frames["imu"]["clock_offset_s"] == pytest.approx(listed[0]["time_offset_s"], abs=1e-12)


def test_bad_input_is_refused_naming_it(client: TestClient, recording) -> None:
    imu = format_imu_csv(recording.imu)
    assert _post(client, imu, lidar="nope").status_code == 404
    wrong = _post(client, imu, sensor="lidar")
    assert wrong.status_code == 404 and "not an IMU of the rig" in wrong.json()["error"]["message"], wrong.text
    empty = _post(client, b"")
    assert empty.status_code == 422 and "imu.csv is empty" in empty.json()["error"]["message"], empty.text
    lines = imu.decode().splitlines()
    lines[40], lines[41] = lines[41], lines[40]
    backwards = _post(client, "\n".join(lines).encode())
    assert backwards.status_code == 422 and "imu.csv" in backwards.json()["error"]["message"], backwards.text
