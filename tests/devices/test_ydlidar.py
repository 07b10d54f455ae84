"""YDLiDAR TG30: the packet parser on hand-built bytes, then the real driver over a pty simulator of the shared yard."""

from __future__ import annotations

import math
import struct
import threading
import time

import numpy as np
import pytest

from backend.core.transforms import from_xyz_ypr, transform_points
from backend.devices.base import DeviceDisconnected, DeviceError, create_device
from backend.devices.ydlidar import YdlidarParser, YdlidarSerial, scan_to_points
from backend.sim.lidar_scene import ROOM_X_M, ROOM_Y_M
from backend.sim.ydlidar_sim import YdlidarSimulator
from tests.conftest import poll

# ---------------------------------------------------------------- hand-built packets


def packet(ct: int, first_deg: float, last_deg: float, dists: list[int], bad_cs: bool = False) -> bytes:
    """AA 55 | CT | LSN | FSA | LSA | CS | samples, little-endian; CS = XOR of the other u16 words."""
    fsa = (round(first_deg * 64) << 1) | 1
    lsa = (round(last_deg * 64) << 1) | 1
    words = [0x55AA, ct | (len(dists) << 8), fsa, lsa, *dists]
    cs = 0
    for w in words:
        cs ^= w
    if bad_cs:
        cs ^= 0x8001
    return struct.pack("<HBBHHH", 0x55AA, ct, len(dists), fsa, lsa, cs) + struct.pack(f"<{len(dists)}H", *dists)


RING = (70 << 1) | 1  # ring start, frequency code 70 -> 7.0 + 3 Hz (TOF)


def one_turn(bad: int | None = None) -> list[bytes]:
    """A coarse turn: ring start at device 0 deg, then 3 packets of 4 samples each 30 deg apart."""
    pkts = [packet(RING, 0.0, 0.0, [1000])]
    for k in range(3):
        first = 30.0 + 120.0 * k
        pkts.append(packet(0, first, first + 90.0, [1000 + 100 * k + i for i in range(4)], bad_cs=(k == bad)))
    return pkts


def test_good_packets_make_one_scan_with_tof_units_and_angles():
    parser = YdlidarParser(min_range_m=0.05, max_range_m=30.0)
    stream = b"".join(one_turn()) + packet(RING, 0.0, 0.0, [1000])
    scans = parser.feed(stream)
    assert len(scans) == 1 and parser.bad_checksums == 0 and parser.skipped_bytes == 0
    scan = scans[0]
    assert scan.scan_frequency_hz == pytest.approx(10.0)
    assert len(scan.ranges_m) == 13 and scan.valid.all()
    assert scan.ranges_m[1:5] == pytest.approx([1.0, 1.001, 1.002, 1.003])  # mm -> m
    # device angles 0, 30, 60, 90, 120 deg (clockwise, 0 backwards) -> theta = pi - device angle
    expected = np.radians([180, 150, 120, 90, 60])
    got = np.mod(scan.angles_rad[:5], 2 * np.pi)
    assert got == pytest.approx(expected, abs=1e-9)


def test_angle_convention_device_to_rep103():
    """Device 180 deg is straight ahead (+x), device 90 deg is left (+y), device 270 deg is right (-y)."""
    parser = YdlidarParser()
    stream = packet(RING, 0.0, 0.0, [1000]) + packet(0, 90.0, 270.0, [2000, 3000, 4000])
    stream += packet(RING, 0.0, 0.0, [1000])
    scan = parser.feed(stream)[0]
    pts = scan_to_points(scan)
    assert pts[1] == pytest.approx([0.0, 2.0, 0.0], abs=1e-9)  # 90 deg: left
    assert pts[2] == pytest.approx([3.0, 0.0, 0.0], abs=1e-9)  # 180 deg: forward
    assert pts[3] == pytest.approx([0.0, -4.0, 0.0], abs=1e-9)  # 270 deg: right
    assert pts[0] == pytest.approx([-1.0, 0.0, 0.0], abs=1e-9)  # 0 deg: backwards
    plain = YdlidarParser(reversion=False, inverted=False).feed(stream)[0]
    assert scan_to_points(plain)[1] == pytest.approx([0.0, 2.0, 0.0], abs=1e-9)  # 90 deg raw = +y
    assert scan_to_points(plain)[2] == pytest.approx([-3.0, 0.0, 0.0], abs=1e-9)


def test_bad_checksum_is_rejected_and_counted():
    parser = YdlidarParser()
    scans = parser.feed(b"".join(one_turn(bad=1)) + packet(RING, 0.0, 0.0, [1000]))
    assert parser.bad_checksums == 1
    assert len(scans) == 1 and len(scans[0].ranges_m) == 9  # the bad packet's 4 samples are gone
    assert 1.1 not in np.round(scans[0].ranges_m, 4)


def test_packets_split_across_feeds_byte_by_byte():
    stream = b"".join(one_turn() + one_turn()) + packet(RING, 0.0, 0.0, [1000])
    whole = YdlidarParser().feed(stream)
    parser = YdlidarParser()
    pieces = [s for i in range(len(stream)) for s in parser.feed(stream[i:i + 1], timestamp_s=float(i))]
    assert len(pieces) == len(whole) == 2
    for a, b in zip(pieces, whole, strict=True):
        assert a.angles_rad == pytest.approx(b.angles_rad) and a.ranges_m == pytest.approx(b.ranges_m)
    assert parser.skipped_bytes == 0 and parser.bad_checksums == 0


def test_garbage_between_packets_resynchronises():
    rng = np.random.default_rng(3)
    pkts = one_turn() + [packet(RING, 0.0, 0.0, [1000])]
    junk = [rng.integers(0, 256, 37, dtype=np.uint8).tobytes(), b"\xaa", b"\xaa\x55\x00", b"\xaa\x55\x00\x05\x03\x00",
            b"\xaa\x55\x00\x02\x01\x00\x03\x00\x00\x00\xff\xff\xff\xff"]  # a fake header with a wrong check code
    stream = b""
    for p, g in zip(pkts, junk, strict=True):
        stream += g + p
    parser = YdlidarParser()
    scans = parser.feed(stream)
    clean = YdlidarParser().feed(b"".join(pkts))
    assert len(scans) == 1 and scans[0].ranges_m == pytest.approx(clean[0].ranges_m)
    assert parser.packets == len(pkts)
    assert parser.skipped_bytes == sum(len(g) for g in junk)  # every garbage byte is accounted for
    assert parser.bad_checksums == 1  # the one fake header with plausible fields and a wrong check code


def test_zero_range_and_out_of_range_samples_are_invalid():
    parser = YdlidarParser(min_range_m=0.05, max_range_m=30.0)
    stream = packet(RING, 0.0, 0.0, [1000]) + packet(0, 10.0, 40.0, [0, 1500, 20, 40000])
    scan = parser.feed(stream + packet(RING, 0.0, 0.0, [1000]))[0]
    assert scan.valid.tolist() == [True, False, True, False, False]
    assert scan.ranges_m[1] == 0.0
    pts = scan_to_points(scan)
    assert pts.shape == (2, 3) and np.all(pts[:, 2] == 0)
    assert np.linalg.norm(pts, axis=1) == pytest.approx([1.0, 1.5])


def test_lost_ring_start_still_splits_scans_and_flush_returns_the_last():
    turn = one_turn()
    stream = b"".join(turn) + packet(RING, 0.0, 0.0, [1000], bad_cs=True) + b"".join(turn[1:])
    parser = YdlidarParser()
    scans = parser.feed(stream)
    assert len(scans) == 1 and len(scans[0].ranges_m) == 13
    rest = parser.flush()
    assert len(rest) == 1 and len(rest[0].ranges_m) == 12 and rest[0].scan_frequency_hz is None


def test_triangle_units_and_angle_correction():
    """Triangle models: quarter-millimetres and the SDK's atan second-stage angle correction."""
    stream = packet(RING, 0.0, 0.0, [4000]) + packet(0, 180.0, 180.0, [4000]) + packet(RING, 0.0, 0.0, [4000])
    scan = YdlidarParser(lidar_type="triangle", reversion=False, inverted=False).feed(stream)[0]
    assert scan.ranges_m[1] == pytest.approx(1.0)
    correction = math.degrees(math.atan(21.8 * (155.3 - 1000.0) / (155.3 * 1000.0)))
    assert math.degrees(scan.angles_rad[1]) % 360 == pytest.approx(180.0 + correction)


def test_parser_reads_a_long_stream_in_serial_sized_chunks():
    sim = YdlidarSimulator()
    data = sim.scan_bytes(50)
    parser = YdlidarParser()
    points = sum(len(s.ranges_m) for i in range(0, len(data), 4096) for s in parser.feed(data[i:i + 4096]))
    assert points == 49 * 2000  # every complete turn (the 50th is still open), whatever the chunk boundaries


# ---------------------------------------------------------------- the driver over a pty


def check_scene(scan_points: np.ndarray, sim: YdlidarSimulator, tol_m: float = 0.002) -> None:
    """Every point is at the simulator's true range along its angle (up to the 1 mm range quantum)
    and lies on the shared yard's surfaces once mapped into base_link (tol in m)."""
    ranges = np.linalg.norm(scan_points, axis=1)
    err = np.abs(ranges - sim.true_ranges(np.arctan2(scan_points[:, 1], scan_points[:, 0])))
    assert err.max() < 0.0005 + 1e-6, f"{(err >= 0.0005 + 1e-6).sum()} ranges off the truth, worst {err.max():.4f} m"
    off = sim.scene.distance_to_mesh(transform_points(sim.T_base_scanner, scan_points))
    assert off.max() < tol_m, f"{(off >= tol_m).sum()} points off the yard's surfaces, worst {off.max():.3f} m"


def wall_range(sim: YdlidarSimulator, theta: float, axis: int, wall_m: float) -> float:
    """Range (m) along scan angle ``theta`` (rad) to the plane ``base[axis] = wall_m`` (m)."""
    T = sim.T_base_scanner
    direction = T[:3, :3] @ np.array([math.cos(theta), math.sin(theta), 0.0])
    return float((wall_m - T[axis, 3]) / direction[axis])


def range_at(points: np.ndarray, theta: float) -> float:
    angles = np.arctan2(points[:, 1], points[:, 0])
    i = np.argmin(np.abs(np.angle(np.exp(1j * (angles - theta)))))
    return float(np.linalg.norm(points[i]))


@pytest.fixture
def sim():
    with YdlidarSimulator() as s:
        yield s


def test_three_full_scans_match_the_scene(sim):
    dev = create_device({"driver": "ydlidar", "port": sim.port})
    assert isinstance(dev, YdlidarSerial)
    with dev:
        assert dev.device_info["model_name"] == "TG30" and dev.device_info["firmware"] == "1.5"
        samples = [dev.read() for _ in range(3)]
    assert [s.meta["scan_index"] for s in samples] == [0, 1, 2]
    for smp in samples:
        assert smp.intensity is None and smp.meta["port"] == sim.port and smp.meta["bad_checksums"] == 0
        assert smp.meta["n_samples"] == 2000 and smp.meta["coverage_deg"] == pytest.approx(360.0, abs=0.5)
        assert smp.meta["scan_frequency_hz"] == pytest.approx(10.0)
        pts = smp.points
        assert pts.shape[1] == 3 and len(pts) == 2000  # a closed yard: every beam returns
        assert np.all(pts[:, 2] == 0)
        check_scene(pts, sim)
        # the demo rig's scanner_2d near the yard's origin: the left wall (y = 5 m) to the left, the back
        # wall (x = -4 m) behind
        assert range_at(pts, math.pi / 2) == pytest.approx(wall_range(sim, math.pi / 2, 1, ROOM_Y_M[1]), abs=0.002)
        assert range_at(pts, math.pi) == pytest.approx(wall_range(sim, math.pi, 0, ROOM_X_M[0]), abs=0.002)
    assert samples[1].timestamp_s > samples[0].timestamp_s  # stamped on arrival, in order (never a rate: load moves it)
    poll(lambda: not sim.scanning, "the scan never stopped", interval_s=0.01)
    assert sim.commands[-1] == 0x65  # close() stopped the scan


def test_moved_and_turned_scanner_still_matches_the_scene():
    T_base_scanner = from_xyz_ypr(np.array([1.5, -0.8, 0.4]), np.radians([40.0, 3.0, -2.0]))
    with (YdlidarSimulator(T_base_scanner=T_base_scanner) as sim,
          create_device({"driver": "ydlidar", "port": sim.port}) as dev):
        check_scene(dev.read().points, sim)


def test_garbage_and_corrupt_packets_are_skipped_and_counted():
    with YdlidarSimulator(garbage_every=5, garbage_len=31, corrupt_every=17, seed=1) as sim:
        with create_device({"driver": "ydlidar", "port": sim.port}) as dev:
            samples = [dev.read() for _ in range(3)]
    for smp in samples:
        check_scene(smp.points, sim)
        assert smp.meta["coverage_deg"] > 340.0  # at most a few 7-degree packets lost
    last = samples[-1].meta
    assert last["bad_checksums"] >= 3 and last["skipped_bytes"] > 31 * 10
    assert [s.meta["scan_index"] for s in samples] == [0, 1, 2]


@pytest.mark.slow
def test_wrong_baud_rate_is_reported():
    with YdlidarSimulator(wrong_baud=True) as sim:
        dev = create_device({"driver": "ydlidar", "port": sim.port})
        t0 = time.monotonic()
        with pytest.raises(DeviceError) as err:
            dev.open()
        assert not isinstance(err.value, DeviceDisconnected)
        assert "baud" in str(err.value) and "512000" in str(err.value) and "no valid YDLiDAR packets" in str(err.value)
        assert time.monotonic() - t0 > 1.5  # it listened before giving up (a loaded machine only adds to it)
        assert "baud" in dev.status


def test_unplug_mid_capture_raises_after_returning_earlier_scans_intact(sim):
    dev = create_device({"driver": "ydlidar", "port": sim.port, "reconnect_timeout_s": 0.5})
    dev.open()
    try:
        got = [dev.read(), dev.read()]
        time.sleep(0.05)  # mid-way through the next turn
        sim.unplug()
        with pytest.raises(DeviceDisconnected, match="unplugged"):
            for _ in range(10):
                got.append(dev.read())  # scans already parsed still come out first
        assert "unplugged" in dev.status
    finally:
        dev.close()
    assert len(got) >= 2
    for smp in got:
        assert smp.meta["n_samples"] == 2000 and smp.meta["coverage_deg"] == pytest.approx(360.0, abs=0.5)
        check_scene(smp.points, sim)


def test_no_reconnect_fails_at_once(sim):
    with create_device({"driver": "ydlidar", "port": sim.port, "reconnect": False}) as dev:
        dev.read()
        sim.unplug()
        with pytest.raises(DeviceDisconnected, match="unplugged"):
            for _ in range(10):
                dev.read()


def test_reconnects_when_the_device_comes_back(sim):
    with create_device({"driver": "ydlidar", "port": sim.port, "reconnect_timeout_s": 5.0}) as dev:
        first = dev.read()
        sim.unplug()
        timer = threading.Timer(0.5, sim.replug)
        timer.start()
        try:
            after = [dev.read() for _ in range(3)]
        finally:
            timer.join()
    assert first.meta["reconnects"] == 0 and after[-1].meta["reconnects"] == 1
    assert after[-1].meta["status"] == "streaming"
    for smp in after[-2:]:
        assert smp.meta["n_samples"] == 2000
        check_scene(smp.points, sim)


def test_missing_port_is_a_clear_error():
    dev = create_device({"driver": "ydlidar", "port": "/dev/does-not-exist-ydlidar"})
    with pytest.raises(DeviceError, match="cannot open serial port"):
        dev.open()


def test_built_in_simulator_is_selectable_as_port_sim():
    with create_device({"driver": "ydlidar", "port": "sim"}) as dev:
        smp = dev.read()
        assert dev.describe() == "ydlidar sim @512000"
    assert smp.meta["port"] == "sim" and len(smp.points) == 2000
