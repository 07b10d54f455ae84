"""The swept-scanner workflow on the demo rig: store a simulated sweep through the ordinary cloud path,
calibrate its geometry against the simulator's truth, accept it into the rig through the one rig service
(and revert), refuse bad results, and the API routes (job, accept, PNG image, errors)."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from fastapi.testclient import TestClient
from scipy.spatial.transform import Rotation

from backend.api.app import create_app
from backend.calib._session import store_cloud
from backend.calib.rig import service as rig_service
from backend.calib.sweep import service
from backend.core.errors import CancelledError, InputError, NotFoundError
from backend.core.result import TransformResult
from backend.core.rig import Frame
from backend.core.sweep_geometry import SweepGeometry
from backend.core.transforms import transform_error
from backend.devices.base import Sample, create_device
from backend.devices.dynamixel_servo import SweptScanner, points_in_base
from backend.devices.image_io import decode_image_bytes
from backend.sim.demo_rig import DEFAULT_SIM_GEOMETRY, SWEEP_NOMINAL_GEOMETRY, demo_rig
from backend.store.session import Session, SessionStore
from tests.conftest import wait_job

SENSOR = "sweep_3d"
SLOT = f"{SENSOR}/sweep"
TRUTH = SweepGeometry.from_dict(DEFAULT_SIM_GEOMETRY)


def read_sweep(device_settings: dict) -> Sample:
    with create_device(device_settings) as device:
        return device.read()


def floor_rms_m(sample: Sample) -> float:
    """RMS height (m) of the yard's floor (z = 0 in base_link) within 4 m, in the truth's base_link."""
    base = points_in_base(sample)
    floor = base[(np.abs(base[:, 2]) < 0.15) & (np.linalg.norm(base[:, :2], axis=1) < 4.0)]
    return float(np.sqrt(np.mean(floor[:, 2] ** 2)))


@pytest.fixture
def session(tmp_path) -> Session:
    return SessionStore(tmp_path).create("sweep", rig=demo_rig())


@pytest.fixture(scope="module")
def nominal_sweep() -> tuple[Sample, float]:
    """One simulated sweep of the demo rig's sweep_3d, assembled with the nominal geometry, and its seconds."""
    started = time.monotonic()
    sample = read_sweep(demo_rig().get(SENSOR).device)
    return sample, time.monotonic() - started


@pytest.fixture(scope="module")
def calibrated(nominal_sweep, tmp_path_factory) -> tuple[Session, str, str, float]:
    """A session holding the nominal sweep and its calibration: (session, capture id, result id, seconds)."""
    session = SessionStore(tmp_path_factory.mktemp("calibrated")).create("sweep", rig=demo_rig())
    capture = service.capture_sweep(session, SENSOR)  # the studio's path: the rig's device, one sweep, stored
    started = time.monotonic()
    result_id = service.solve_session(session, SENSOR)
    return session, capture.id, result_id, time.monotonic() - started


@pytest.mark.slow
def test_capture_sweep_stores_one_sweep_of_the_rigs_device(calibrated, nominal_sweep):
    session, capture_id, _, _ = calibrated
    [record] = session.captures(SENSOR)
    assert record.id == capture_id and record.device.startswith("swept_scanner servo sim")
    assert record.meta["geometry"] == SWEEP_NOMINAL_GEOMETRY and len(record.meta["step_counts"]) == 173
    points, _ = session.capture_cloud(SENSOR, capture_id)
    assert len(points) == sum(record.meta["step_counts"]) == len(nominal_sweep[0].points)
    with pytest.raises(InputError, match="lidar_top.*not a swept scanner"):
        service.capture_sweep(session, "lidar_top")


# ---------------------------------------------------------------- storage


@pytest.mark.slow
def test_a_stored_sweep_gives_its_raw_scans_back(nominal_sweep, session):
    sample, seconds = nominal_sweep
    print(f"one simulated sweep (open + read): {seconds:.1f} s, {len(sample.points):,} points")
    record = store_cloud(session, SENSOR, sample, device="sim")
    meta = record.meta
    assert meta["geometry"] == SWEEP_NOMINAL_GEOMETRY and meta["true_geometry"] == DEFAULT_SIM_GEOMETRY
    assert sum(meta["step_counts"]) == record.n_points == len(sample.points) and len(meta["step_counts"]) == 173
    assert "points_scanner" not in meta and "point_step" not in meta  # arrays are not kept: they come back
    assert service.is_swept(session, SENSOR) and not service.is_swept(session, "lidar_top")
    stored = service.capture_scans(session, SENSOR, service.swept_capture(session, SENSOR))
    raw = SweptScanner.scans_of(sample)
    assert len(stored) == len(raw)
    for (a, p, i), (a0, p0, i0) in zip(stored, raw, strict=True):
        assert a == a0 and i == pytest.approx(i0)
        assert np.abs(p - p0).max() < 1e-5  # float32 storage: micrometres at these ranges


def test_storable_meta_keeps_json_dicts_and_drops_arrays():
    sample = Sample(0.0, meta={"geometry": {"axis": [1.0, 0.0, 0.0], "zero_offset_rad": 0.1}, "n": 3,
                               "steps": [1, 2], "array": np.zeros(3), "nested": {"bad": np.zeros(2)}})
    assert sample.storable_meta() == {"geometry": {"axis": [1.0, 0.0, 0.0], "zero_offset_rad": 0.1}, "n": 3,
                                      "steps": [1, 2]}


# ---------------------------------------------------------------- calibrate, accept, revert


@pytest.mark.slow
def test_calibration_of_a_stored_sweep_recovers_the_truth(calibrated):
    session, capture_id, result_id, seconds = calibrated
    print(f"calibration of one sweep: {seconds:.1f} s")
    record = session.result(result_id)
    assert record["kind"] == "sweep" and record["sensor"] == SENSOR
    assert record["inputs"] == [capture_id] and record["capture"] == capture_id
    assert record["initial"] == SweepGeometry.from_dict(SWEEP_NOMINAL_GEOMETRY).to_dict()
    assert record["settings"]["up_mount"] == pytest.approx([0.0, 0.0, 1.0])  # the mount is level
    assert record["converged"] and record["floor_found"] and record["planes"] >= 4
    g = SweepGeometry.from_dict(record["geometry"])
    error_t = g.T_servo_scanner[:3, 3] - TRUTH.T_servo_scanner[:3, 3]
    error_zero = g.zero_offset_rad - TRUTH.zero_offset_rad
    error_tilt = Rotation.from_matrix(TRUTH.T_servo_scanner[:3, :3].T @ g.T_servo_scanner[:3, :3]).as_rotvec()
    assert np.abs(error_t).max() < 0.002 and abs(math.degrees(error_zero)) < 0.05
    assert np.degrees(np.abs(error_tilt)).max() < 0.1
    std = record["parameter_std"]
    assert abs(error_t[1]) <= 3 * std["offset_u_m"] and abs(error_t[2]) <= 3 * std["offset_v_m"]
    assert abs(error_zero) <= 3 * std["zero_offset_rad"]
    # the one transform result, named by the rig: the scanner's pose in the sensor's (mount) frame at servo zero
    transform = TransformResult.from_record(record["transform"])
    assert (transform.kind, transform.parent, transform.child) == ("sweep", SENSOR, f"{SENSOR}_scanner")
    assert record["std"] == transform.std and transform.std["trans_m"][0] is None  # along the axis: unseen
    error_m, error_deg = transform_error(transform.T_parent_child, TRUTH.T_mount_scanner(0.0))
    assert np.all(np.abs(error_m[1:]) <= 3 * np.array(transform.std["trans_m"][1:]))
    assert np.all(np.abs(error_deg) <= 3 * np.array(transform.std["rot_deg"]) + 0.006)
    assert record["rms_after_m"] < 0.6 * record["rms_before_m"]
    # within its tolerances (2 mm, 0.1 deg) and the even and odd servo steps agree: trusted, and it says why
    assert record["verdict"]["level"] == "trusted", record["verdict"]
    assert any("cross-check of the even and odd servo steps" in r for r in record["verdict"]["reasons"])


@pytest.mark.slow
def test_accept_writes_the_geometry_into_the_rig_and_reverts(calibrated, nominal_sweep):
    session, _, result_id, _ = calibrated
    before_rig = session.rig.get(SENSOR).T_parent_child.copy()
    rig_service.accept(session, result_id)
    record = session.result(result_id)
    device = session.rig.get(SENSOR).device
    assert device["geometry"] == record["geometry"] and device["driver"] == "swept_scanner"
    assert session.accepted(SLOT) == result_id and rig_service.slot_of(record) == SLOT
    assert np.allclose(session.rig.get(SENSOR).T_parent_child, before_rig, atol=1e-9)  # the mount stays
    assert Session.load(session.path).rig.get(SENSOR).device["geometry"] == record["geometry"]  # saved

    # the next sweep is assembled with it, and it is flatter than with the nominal geometry
    calibrated_sweep = read_sweep(device)
    assert calibrated_sweep.meta["geometry"] == record["geometry"]
    flat, bent = floor_rms_m(calibrated_sweep), floor_rms_m(nominal_sweep[0])
    print(f"floor RMS: {flat * 1000:.1f} mm calibrated, {bent * 1000:.1f} mm nominal")
    assert flat < 0.5 * bent and flat < 0.015

    # a second result, then back to the first: every result stays in the history
    other = {k: v for k, v in record.items() if k not in ("id", "sensor", "created", "inputs")}
    other["geometry"] = SWEEP_NOMINAL_GEOMETRY
    other_id = session.add_result(SENSOR, other, inputs=record["inputs"])
    rig_service.accept(session, other_id)
    assert session.rig.get(SENSOR).device["geometry"] == SWEEP_NOMINAL_GEOMETRY
    rig_service.accept(session, result_id)
    assert session.rig.get(SENSOR).device["geometry"] == record["geometry"]
    assert [a.result_id for a in session.acceptance_log] == [result_id, other_id, result_id]
    assert [r["id"] for r in session.results(SENSOR, "sweep")] == [result_id, other_id]


@pytest.mark.slow
def test_bad_results_are_refused_and_the_rig_stays(calibrated):
    session, _, result_id, _ = calibrated
    record = session.result(result_id)
    kept = {k: v for k, v in record.items() if k not in ("id", "sensor", "created", "inputs")}
    geometry_before = dict(session.rig.get(SENSOR).device["geometry"])
    accepted_before = session.accepted(SLOT)
    bad = {
        "did not converge": kept | {"converged": False, "warnings": ["not converged after 10 iterations"]},
        "leaves parameters undetermined": kept | {"covariance": [[None] * 5] * 5},
        "made the planes less flat": kept | {"rms_after_m": 2 * kept["rms_before_m"]},
    }
    for reason, doctored in bad.items():
        doctored["geometry"] = SWEEP_NOMINAL_GEOMETRY
        bad_id = session.add_result(SENSOR, doctored, inputs=[])
        with pytest.raises(InputError, match=f"{bad_id} {reason} and cannot be accepted") as info:
            rig_service.accept(session, bad_id)
        assert info.value.input == "result"
        assert session.rig.get(SENSOR).device["geometry"] == geometry_before
        assert session.accepted(SLOT) == accepted_before
    # what the accept route checks before it hands over to the rig service
    session.add_sensor(Frame("sweep_b", "base_link", kind="lidar3d", device=demo_rig().get(SENSOR).device))
    with pytest.raises(InputError, match=f"{result_id} belongs to {SENSOR}, not sweep_b"):
        service.sweep_result(session, "sweep_b", result_id)
    with pytest.raises(InputError, match="not a swept scanner"):
        service.sweep_result(session, "lidar_top", result_id)
    other_kind = session.add_result(SENSOR, {"kind": "lidar_lidar"}, inputs=[])
    with pytest.raises(InputError, match=f"{other_kind} is a lidar_lidar result, not sweep"):
        service.sweep_result(session, SENSOR, other_kind)


@pytest.mark.slow
def test_calibration_can_be_cancelled_and_leaves_no_result(nominal_sweep, session):
    store_cloud(session, SENSOR, nominal_sweep[0], device="sim")
    calls = []

    def progress(fraction: float, message: str) -> None:
        calls.append(message)
        if len(calls) > 1:  # inside the solver
            raise CancelledError("cancelled")

    with pytest.raises(CancelledError):
        service.solve_session(session, SENSOR, progress=progress)
    assert session.results(SENSOR) == []


@pytest.mark.slow
def test_sweep_image_of_a_stored_sweep(calibrated):
    session, capture_id, result_id, _ = calibrated
    image = service.sweep_image(session, SENSOR, capture_id)
    assert image.dtype == np.uint8 and image.shape[0] == 173
    assert abs(image.shape[1] - 1081) <= 2  # one column per 0.25 deg beam over 270 deg
    assert (image > 0).mean() > 0.6 and (image == 255).sum() > 10  # the bright board
    ranged = service.sweep_image(session, SENSOR, capture_id, result_id=result_id, mode="range")
    assert ranged.shape == image.shape and np.array_equal(ranged > 0, image > 0)
    with pytest.raises(InputError, match="'intensity' or 'range'"):
        service.sweep_image(session, SENSOR, capture_id, mode="colour")  # type: ignore[arg-type]


# ---------------------------------------------------------------- clear errors


def test_errors_name_the_sensor_and_the_capture(session):
    with pytest.raises(InputError, match="'lidar_top' is not a swept scanner") as info:
        service.solve_session(session, "lidar_top")
    assert info.value.input == "sensor"
    with pytest.raises(NotFoundError, match="no sensor or frame named 'nope'"):
        service.solve_session(session, "nope")
    with pytest.raises(InputError, match="no sweep captured for sweep_3d yet") as info:
        service.solve_session(session, SENSOR)
    assert info.value.input == SENSOR and info.value.status_code == 422
    plain = store_cloud(session, SENSOR, Sample(0.0, points=np.ones((5, 3))), device="upload")
    with pytest.raises(InputError, match=f"capture {plain.id} of sweep_3d holds no sweep .*step_counts") as info:
        service.solve_session(session, SENSOR, plain.id)
    assert info.value.input == "capture"
    with pytest.raises(NotFoundError, match="no cloud capture '00042' for sensor 'sweep_3d'"):
        service.solve_session(session, SENSOR, "00042")
    # a sweep too short to calibrate: the solver says so
    points = np.column_stack([np.linspace(1, 2, 50), np.zeros(50), np.zeros(50)])
    short = Sample(0.0, points=points, meta={"servo_angles_rad": [0.0, 0.1], "step_counts": [25, 25],
                                             "geometry": SWEEP_NOMINAL_GEOMETRY})
    store_cloud(session, SENSOR, short, device="sim")
    with pytest.raises(InputError, match="too short to calibrate"):
        service.solve_session(session, SENSOR)
    broken = Sample(0.0, points=points, meta={"servo_angles_rad": [0.0, 0.1], "step_counts": [25, 20],
                                              "geometry": SWEEP_NOMINAL_GEOMETRY})
    broken_id = store_cloud(session, SENSOR, broken, device="sim").id
    with pytest.raises(InputError, match=f"capture {broken_id} of sweep_3d: step_counts"):
        service.solve_session(session, SENSOR)


# ---------------------------------------------------------------- API


@pytest.fixture
def client(tmp_path):
    store = SessionStore(tmp_path)
    store.create("demo", rig=demo_rig())
    with TestClient(create_app(store)) as client:
        yield client, store.get("demo")


def test_api_errors(client):
    client, _ = client
    base = "/api/sessions/demo/sensors"
    response = client.post(f"{base}/lidar_top/sweep/calibrate", json={})
    assert response.status_code == 422
    assert response.json()["error"] == {"message": "sensor 'lidar_top' is not a swept scanner (its driver is "
                                                   "'simulated_lidar', not 'swept_scanner')", "input": "sensor"}
    response = client.post(f"{base}/sweep_3d/sweep/calibrate", json={})
    assert response.status_code == 422 and "no sweep captured for sweep_3d" in response.json()["error"]["message"]
    response = client.post(f"{base}/ghost/sweep/calibrate", json={})
    assert response.status_code == 404 and "'ghost'" in response.json()["error"]["message"]
    response = client.post(f"{base}/sweep_3d/sweep/calibrate", json={"capture_id": "00007"})
    assert response.status_code == 404 and response.json()["error"]["input"] == "capture"
    response = client.get(f"{base}/sweep_3d/sweep/image/00007")
    assert response.status_code == 404 and "'00007'" in response.json()["error"]["message"]
    response = client.get(f"{base}/sweep_3d/sweep/image/00007?mode=colour")
    assert response.status_code == 422 and response.json()["error"]["input"] == "query.mode"
    response = client.post(f"{base}/sweep_3d/sweep/accept", json={"result_id": "r0099"})
    assert response.status_code == 404 and response.json()["error"]["input"] == "result"


@pytest.mark.slow
def test_api_calibrate_image_accept(client, nominal_sweep):
    client, session = client
    capture = store_cloud(session, SENSOR, nominal_sweep[0], device="sim")
    base = "/api/sessions/demo/sensors/sweep_3d/sweep"
    job = client.post(f"{base}/calibrate", json={})
    assert job.status_code == 202 and job.json()["state"] == "running"
    status = wait_job(client, job.json()["id"], timeout_s=120)
    assert status["state"] == "done", status
    record = client.get(f"/api/sessions/demo/results/{status['result_id']}").json()
    assert record["kind"] == "sweep" and record["capture"] == capture.id and record["converged"]

    png = client.get(f"{base}/image/{capture.id}", params={"mode": "range", "result_id": status["result_id"]})
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    image = decode_image_bytes(png.content, "sweep.png", grayscale=True)
    assert image.shape[0] == 173 and abs(image.shape[1] - 1081) <= 2

    accepted = client.post(f"{base}/accept", json={"result_id": status["result_id"]})
    assert accepted.status_code == 200 and accepted.json()["accepted"] == {SLOT: status["result_id"]}
    rig = client.get("/api/sessions/demo/rig").json()
    frame = next(f for f in rig["frames"] if f["name"] == SENSOR)
    assert frame["device"]["geometry"] == record["geometry"]
    unconverged = session.add_result(SENSOR, {k: v for k, v in record.items()
                                              if k not in ("id", "sensor", "created", "inputs")}
                                     | {"converged": False}, inputs=[])
    refused = client.post(f"{base}/accept", json={"result_id": unconverged})
    assert refused.status_code == 422 and "did not converge" in refused.json()["error"]["message"]
    assert refused.json()["error"]["input"] == "result"
    elsewhere = client.post("/api/sessions/demo/sensors/lidar_top/sweep/accept", json={"result_id": unconverged})
    assert elsewhere.status_code == 422 and "not a swept scanner" in elsewhere.json()["error"]["message"]
