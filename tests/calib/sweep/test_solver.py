"""Swept 2D scanner: sweep geometry maths, the Dynamixel servo over its byte-level simulator, the
swept_scanner driver against ray-cast ground truth, the sweep calibration and the LiDAR image."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from backend.calib.sweep.solver import SweepCalibrationSettings, calibrate_sweep
from backend.core.errors import InputError
from backend.core.result import TransformResult
from backend.core.sweep_geometry import SweepGeometry, intensity_image
from backend.core.transforms import from_xyz_ypr, make_T, transform_error, transform_points
from backend.devices.base import DeviceError, create_device
from backend.devices.dynamixel_servo import (
    SIM_LATENCY_MS,
    DynamixelServo,
    SweptScanner,
    angle_to_ticks,
    points_in_base,
)
from backend.sim import dynamixel_sim as dsim
from backend.sim.demo_rig import DEFAULT_SIM_GEOMETRY
from backend.sim.dynamixel_sim import DynamixelSimulator
from backend.sim.lidar_scene import LidarScene

TRUTH = SweepGeometry.from_dict(DEFAULT_SIM_GEOMETRY)

# ---------------------------------------------------------------- geometry


def test_assemble_matches_known_transforms():
    T_servo_scanner = from_xyz_ypr(np.array([0.02, 0.0, 0.05]), np.radians([2.0, -1.0, 0.0]))
    g = SweepGeometry(axis=np.array([1.0, 0.0, 0.0]), T_servo_scanner=T_servo_scanner, zero_offset_rad=0.1)
    # by hand: a point 1 m ahead of a scanner with no offset, servo at 90 deg about x, stays on the axis
    plain = SweepGeometry()
    p, _, _ = plain.assemble([(math.pi / 2, np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), None)])
    assert p == pytest.approx(np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), abs=1e-12)  # y rolls onto z
    # the offset rolls with the servo: at 90 deg + 0, (0, 0, 0.05) goes to (0, -0.05, 0)
    off = SweepGeometry(T_servo_scanner=make_T(np.eye(3), [0.0, 0.0, 0.05]))
    p, _, _ = off.assemble([(math.pi / 2, np.zeros((1, 3)), None)])
    assert p[0] == pytest.approx([0.0, -0.05, 0.0], abs=1e-12)

    rng = np.random.default_rng(0)
    scans = [(a, rng.uniform(-5, 5, (20, 3)) * [1, 1, 0], rng.uniform(0, 255, 20)) for a in np.radians([-80, 0, 33])]
    points, intensity, angles = g.assemble(scans)
    assert points.shape == (60, 3) and intensity.dtype == np.float32 and angles.shape == (60,)
    for k, (a, pts, inten) in enumerate(scans):
        R = Rotation.from_rotvec([a + 0.1, 0.0, 0.0]).as_matrix()
        expected = transform_points(make_T(R, np.zeros(3)) @ T_servo_scanner, pts)
        assert points[20 * k:20 * k + 20] == pytest.approx(expected, abs=1e-12)
        assert g.T_mount_scanner(a) == pytest.approx(make_T(R, np.zeros(3)) @ T_servo_scanner, abs=1e-12)
        assert intensity[20 * k:20 * k + 20] == pytest.approx(inten.astype(np.float32))
        assert angles[20 * k:20 * k + 20] == pytest.approx(a)


def test_any_axis_and_dict_round_trip():
    axis = np.array([0.2, 1.0, -0.1])
    g = SweepGeometry(axis=axis, T_servo_scanner=from_xyz_ypr(np.array([0.01, 0.02, 0.03]), np.zeros(3)),
                      zero_offset_rad=-0.05)
    pts = np.array([[1.0, 2.0, 0.0], [-3.0, 0.5, 0.0]])
    out = g.transform(pts, np.array([0.7, -1.2]))
    unit = axis / np.linalg.norm(axis)
    for i, a in enumerate([0.7, -1.2]):
        R = Rotation.from_rotvec(unit * (a - 0.05)).as_matrix()
        assert out[i] == pytest.approx(R @ (pts[i] + [0.01, 0.02, 0.03]), abs=1e-12)
    again = SweepGeometry.from_dict(g.to_dict())
    assert again.axis == pytest.approx(unit) and again.zero_offset_rad == -0.05
    assert again.T_servo_scanner == pytest.approx(g.T_servo_scanner)
    with pytest.raises(ValueError, match="unknown"):
        SweepGeometry.from_dict({"axes": [1, 0, 0]})


# ---------------------------------------------------------------- Dynamixel protocol 2.0


def test_simulator_speaks_the_sdk_crc_and_rejects_bad_crc():
    from dynamixel_sdk import Protocol2PacketHandler

    data = bytes(range(40))
    assert dsim.crc16(data) == Protocol2PacketHandler().updateCRC(0, list(data), len(data))
    sim = DynamixelSimulator()  # no pty needed to talk bytes
    ping = sim.handle(dsim.instruction_packet(1, dsim.INST_PING))
    assert ping[:4] == b"\xff\xff\xfd\x00" and ping[7] == 0x55 and ping[8] == 0
    assert struct.unpack_from("<H", ping, 9)[0] == 1020
    assert dsim.crc16(ping[:-2]) == struct.unpack_from("<H", ping, len(ping) - 2)[0]
    goal = struct.pack("<Hi", dsim.ADDR_GOAL_POSITION, 3000)
    bad = sim.handle(dsim.instruction_packet(1, dsim.INST_WRITE, goal, bad_crc=True))
    assert bad[8] == dsim.ERR_CRC and sim.crc_errors == 1 and sim.goal_ticks() == 2048  # not executed
    ok = sim.handle(dsim.instruction_packet(1, dsim.INST_WRITE, goal))
    assert ok[8] == 0 and sim.goal_ticks() == 3000
    limit = sim.handle(dsim.instruction_packet(1, dsim.INST_WRITE, struct.pack("<Hi", 116, 5000)))
    assert limit[8] == dsim.ERR_DATA_LIMIT
    access = sim.handle(dsim.instruction_packet(1, dsim.INST_WRITE, struct.pack("<Hi", 132, 10)))
    assert access[8] == dsim.ERR_ACCESS
    assert sim.handle(dsim.instruction_packet(7, dsim.INST_PING)) == b""  # another servo's packet
    # byte stuffing: FF FF FD inside the parameters gets an extra FD, and comes out again
    body = bytes([dsim.INST_WRITE, 0xFF, 0xFF, 0xFD, 0x01])
    packet = dsim.build_packet(1, body)
    assert b"\xff\xff\xfd\xfd" in packet[7:] and dsim.unstuff(packet[7:-2]) == body


def test_servo_round_trip_over_pty_with_corrupt_status_packets():
    with DynamixelSimulator(speed_deg_s=600.0, corrupt_every=3) as sim:
        servo = DynamixelServo(sim.port, latency_ms=SIM_LATENCY_MS)  # a simulator thread on a maybe loaded host
        servo.open()
        try:
            assert servo.model_number == 1020
            got = servo.move_to(math.radians(30.0), wait=True)
            assert sim.goal_ticks() == angle_to_ticks(math.radians(30.0)) == 2389
            assert got == pytest.approx(math.radians(30.0), abs=math.radians(0.1))
            assert servo.read_ticks() == sim.present_ticks() == 2389
            servo.move_to(math.radians(-45.0))
            assert math.degrees(servo.read_angle()) == pytest.approx(-45.0, abs=0.1)
            assert sim.true_angle_rad() == pytest.approx(math.radians(-45.0), abs=math.radians(0.09))
            assert sim.corrupted_sent > 0 and servo.retried >= sim.corrupted_sent  # bad CRCs were retried
            with pytest.raises(DeviceError, match="outside"):
                servo.move_to(math.radians(200.0))
        finally:
            servo.close()


def test_servo_that_never_answers_is_reported():
    with DynamixelSimulator(dxl_id=3) as sim:
        servo = DynamixelServo(sim.port, dxl_id=1, retries=1)
        with pytest.raises(DeviceError, match="no valid answer"):
            servo.open()


# ---------------------------------------------------------------- the swept scanner


@pytest.mark.slow
def test_full_sweep_with_true_geometry_is_a_flat_floor(full_sweep):
    sample, _ = full_sweep
    meta = sample.meta
    assert meta["steps"] == 173 and len(meta["servo_angles_rad"]) == 173 and meta["frame"] == "mount"
    assert np.degrees(meta["servo_angles_rad"][0]) == pytest.approx(-90, abs=0.1)
    assert np.degrees(meta["servo_angles_rad"][-1]) == pytest.approx(90, abs=0.1)
    assert sample.points.shape[0] > 50_000 and sample.intensity.shape == (len(sample.points),)
    assert meta["simulated"] and meta["true_geometry"] == DEFAULT_SIM_GEOMETRY
    base = points_in_base(sample)
    assert base[:, 2].min() < 0.0 and base[:, 2].max() > 2.5  # floor and upper walls: a half sphere
    floor = base[(np.abs(base[:, 2]) < 0.1) & (np.linalg.norm(base[:, :2], axis=1) < 4.0)]
    assert len(floor) > 5000
    assert abs(floor[:, 2].mean()) < 0.002 and floor[:, 2].std() < 0.012  # planar: range noise only
    distance = LidarScene().distance_to_mesh(base[::20])
    assert np.median(distance) < 0.01
    # assembled with a wrong geometry the same floor is bent and tilted
    wrong = SweepGeometry().transform(meta["points_scanner"], np.repeat(meta["servo_angles_rad"],
                                                                        np.bincount(meta["point_step"])))
    wrong_base = transform_points(np.asarray(meta["T_base_mount"]), wrong)
    assert np.median(LidarScene().distance_to_mesh(wrong_base[::20])) > 1.5 * np.median(distance)
    # raw scans come back out for calibration
    scans = SweptScanner.scans_of(sample)
    assert len(scans) == 173 and sum(len(s[1]) for s in scans) == len(sample.points)
    again, _, _ = TRUTH.assemble(scans)
    assert again == pytest.approx(sample.points)


@pytest.mark.slow
def test_sweep_calibration_recovers_truth_from_a_wrong_start(full_sweep):
    sample, _ = full_sweep
    scans = SweptScanner.scans_of(sample)
    start = TRUTH.copy()
    start.T_servo_scanner = np.eye(4)  # nominal mounting: tilt unknown
    start.T_servo_scanner[:3, 3] = TRUTH.T_servo_scanner[:3, 3] + [0.0, 0.012, -0.016]  # 2 cm off, perpendicular
    start.zero_offset_rad = TRUTH.zero_offset_rad - math.radians(1.0)
    result = calibrate_sweep(scans, start, SweepCalibrationSettings(up_mount=(0.0, 0.0, 1.0)))
    g = result.geometry
    error_t = g.T_servo_scanner[:3, 3] - TRUTH.T_servo_scanner[:3, 3]
    error_zero = g.zero_offset_rad - TRUTH.zero_offset_rad
    error_tilt = Rotation.from_matrix(TRUTH.T_servo_scanner[:3, :3].T @ g.T_servo_scanner[:3, :3]).as_rotvec()
    assert np.abs(error_t).max() < 0.002
    assert abs(math.degrees(error_zero)) < 0.1
    assert np.degrees(np.abs(error_tilt)).max() < 0.1
    # the sigmas cover the errors (u, v = mount y, z for an axis along x)
    std = result.parameter_std
    assert set(std) == {"offset_u_m", "offset_v_m", "zero_offset_rad", "tilt_u_rad", "tilt_v_rad"}
    assert abs(error_t[1]) < 3 * std["offset_u_m"] and abs(error_t[2]) < 3 * std["offset_v_m"]
    assert abs(error_zero) < 3 * std["zero_offset_rad"]
    assert abs(error_tilt[1]) < 3 * std["tilt_u_rad"] + 1e-4 and abs(error_tilt[2]) < 3 * std["tilt_v_rad"] + 1e-4
    assert all(0 < s < 0.003 for s in std.values())
    assert result.rms_after_m < 0.6 * result.rms_before_m and result.rms_after_m < 0.012
    assert result.planes >= 4 and result.floor_found and result.converged
    # the one transform result: the scanner's pose at servo zero, its sigmas covering its error, the offset
    # along the axis (mount x) undetermined, every other parameter propagated from the geometry's sigmas
    transform = result.transform
    assert (transform.kind, transform.method, transform.parent, transform.child) == ("sweep", "planes", "mount",
                                                                                     "scanner")
    error_m, error_deg = transform_error(transform.T_parent_child, TRUTH.T_mount_scanner(0.0))
    assert abs(error_m[0]) < 1e-12  # kept as given, and the truth's is the same
    assert result.std == transform.std and transform.std["trans_m"][0] is None
    trans_m, rot_deg = np.array(transform.std["trans_m"][1:]), np.array(transform.std["rot_deg"])
    assert np.all((trans_m > 0) & (trans_m < 0.003)) and np.all((rot_deg > 0) & (rot_deg < 0.2))
    assert np.all(np.abs(error_m[1:]) <= 3 * trans_m) and np.all(np.abs(error_deg) <= 3 * rot_deg + 0.006)
    # with the axis along mount x: y, z are the offsets, the rotation about x the servo zero
    assert transform.std["trans_m"][1] == pytest.approx(std["offset_u_m"], rel=0.05)
    assert transform.std["rot_deg"][0] == pytest.approx(math.degrees(std["zero_offset_rad"]), rel=0.05)
    assert transform.residuals["rms_after_m"] == result.rms_after_m and transform.converged
    assert transform.verdict is not None and transform.warnings is result.warnings
    summary = result.summary()
    assert summary["geometry"]["axis"] == [1.0, 0.0, 0.0] and summary["std"] == transform.std
    assert summary["verdict"] == transform.verdict.to_dict()
    assert set(summary["parameter_std"]) == set(std)
    record = result.to_record()
    assert record["kind"] == "sweep" and record["converged"]
    assert TransformResult.from_record(record["transform"]).std == transform.std


@pytest.mark.slow
def test_sweep_calibration_rejects_short_or_empty_sweeps(full_sweep):
    scans = SweptScanner.scans_of(full_sweep[0])
    with pytest.raises(InputError, match="at least 10"):
        calibrate_sweep(scans[:9])
    with pytest.raises(InputError, match="finite points"):
        calibrate_sweep([(a, p[:5], i[:5]) for a, p, i in scans[:20]])
    # without a floor reference the zero offset is kept, and said so
    result = calibrate_sweep(scans[::4], TRUTH, SweepCalibrationSettings(estimate_tilt=False, jackknife_groups=0))
    assert "zero_offset_rad" not in result.parameter_std and result.geometry.zero_offset_rad == TRUTH.zero_offset_rad
    assert any("zero offset" in w for w in result.warnings)
    # only the offset perpendicular to the axis is estimated: the transform's rotation is undetermined
    assert result.std["rot_deg"] == [None, None, None] and result.std["trans_m"][0] is None
    assert all(s is not None and s > 0 for s in result.std["trans_m"][1:])


@pytest.mark.slow
def test_intensity_image_of_the_sweep(full_sweep):
    sample, _ = full_sweep
    meta = sample.meta
    servo = np.repeat(meta["servo_angles_rad"], np.bincount(meta["point_step"]))
    image = intensity_image(sample.points, sample.intensity, servo, meta["scan_angles_rad"], (173, 540),
                            scan_range_rad=(-math.radians(135), math.radians(135)))
    assert image.intensity.shape == image.range.shape == image.range_m.shape == (173, 540)
    assert image.intensity.dtype == np.uint8 and image.range.dtype == np.uint8
    filled = image.intensity > 0
    assert filled.mean() > 0.6  # most directions of the half sphere have a return
    assert len(np.unique(image.intensity[filled])) > 50 and image.intensity[filled].std() > 20
    assert np.isnan(image.range_m[~filled]).all() and np.nanmax(image.range_m) < 30
    assert image.servo_angles_rad[0] == pytest.approx(math.radians(-90), abs=1e-3)
    # the board (paper white, 230) is the brightest thing in the yard: it shows as a bright patch
    assert (image.intensity == 255).sum() > 10


def test_swept_scanner_drives_a_real_scanner_driver_and_checks_settings():
    dev = create_device({"driver": "swept_scanner", "servo_port": "sim", "steps": 3, "start_deg": -10,
                         "end_deg": 10, "scanner": {"driver": "ydlidar", "port": "sim"}})
    dev.open()
    try:
        sample = dev.read()
    finally:
        dev.close()
    assert sample.meta["steps"] == 3 and np.bincount(sample.meta["point_step"]).min() > 1000
    assert np.degrees(sample.meta["servo_angles_rad"]) == pytest.approx([-10, 0, 10], abs=0.1)
    assert (sample.intensity == 0).all() and "simulated" not in sample.meta
    with pytest.raises(DeviceError, match="simulated servo"):
        create_device({"driver": "swept_scanner", "servo_port": "/dev/ttyUSB0", "scanner": {"driver": "sim"}})
    with pytest.raises(DeviceError, match="bad geometry"):
        create_device({"driver": "swept_scanner", "servo_port": "sim", "geometry": {"axis": [0, 0, 0]}})
    with pytest.raises(DeviceError, match="cannot open"):
        create_device({"driver": "swept_scanner", "servo_port": "/nonexistent/tty", "scanner": {"driver": "ydlidar",
                                                                                                "port": "sim"}}).open()


@pytest.mark.slow
def test_a_hokuyo_on_the_servo_is_calibrated_like_the_ydlidar():
    """The servo-scanner rig: a UTM-30LX-EW speaking SCIP 2.0 (its simulator on 127.0.0.1) on the Dynamixel (its
    simulator on a pty), both byte-level; the sweep's calibration recovers the true geometry from a wrong start."""
    with create_device({"driver": "swept_scanner", "servo_port": "sim", "steps": 58, "geometry": DEFAULT_SIM_GEOMETRY,
                        "scanner": {"driver": "hokuyo", "host": "sim"}}) as device:
        sample = device.read()
    assert sample.meta["simulated"] and sample.meta["true_geometry"] == DEFAULT_SIM_GEOMETRY
    assert len(sample.meta["servo_angles_rad"]) == 58 and np.bincount(sample.meta["point_step"]).min() > 100
    assert sample.intensity.max() > 5000  # the Hokuyo's own intensities, the white board the brightest
    base = points_in_base(sample)
    assert np.median(LidarScene().distance_to_mesh(base[::20])) < 0.01
    start = TRUTH.copy()
    start.T_servo_scanner = np.eye(4)
    start.T_servo_scanner[:3, 3] = TRUTH.T_servo_scanner[:3, 3] + [0.0, 0.012, -0.016]
    start.zero_offset_rad = TRUTH.zero_offset_rad - math.radians(1.0)
    result = calibrate_sweep(SweptScanner.scans_of(sample), start, SweepCalibrationSettings(up_mount=(0.0, 0.0, 1.0)))
    error_t = result.geometry.T_servo_scanner[:3, 3] - TRUTH.T_servo_scanner[:3, 3]
    assert np.abs(error_t[1:]).max() < 0.002 and result.converged
    assert abs(math.degrees(result.geometry.zero_offset_rad - TRUTH.zero_offset_rad)) < 0.1
