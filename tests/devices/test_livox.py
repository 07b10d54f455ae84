"""Livox SDK 1: the wire format, the byte-level UDP simulator (127.0.0.1) and the ``livox`` driver through it, and
accumulating a static sensor's frames into a dense cloud with its coverage.

Tolerances: the simulator's range noise is ``SIGMA_M`` (1-sigma); the packets carry whole millimetres, so a decoded
point lies within ``QUANT_M`` (half a millimetre on each axis) of the noisy return along the true ray.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable

import numpy as np
import pytest

from backend.core.accumulation import CloudAccumulator, FieldOfView, coverage_of
from backend.core.errors import InputError
from backend.core.transforms import transform_points
from backend.devices.accumulate import read_accumulated
from backend.devices.base import DeviceDisconnected, DeviceError, Sample, check_settings, create_device
from backend.devices.livox import LIVOX_FOV
from backend.devices.livox_packets import (
    CMD_HANDSHAKE,
    CMD_HEARTBEAT,
    CMD_SET_GENERAL,
    CMD_TYPE_ACK,
    CMD_TYPE_MESSAGE,
    CMD_TYPE_REQUEST,
    DATA_TYPE_DUAL_EXTEND_CARTESIAN,
    DATA_TYPE_EXTEND_CARTESIAN,
    ETH_HEADER,
    HANDSHAKE,
    STANDARD_GRAVITY_M_S2,
    Frame,
    data_headers,
    decode_imu,
    decode_points,
    pack_frame,
    packet_size,
    packet_times_ns,
    parse_frame,
)
from backend.sim.lidar_scene import LidarScene
from backend.sim.livox_pattern import PATTERNS
from backend.sim.livox_sim import LivoxSimulator

SIGMA_M = 0.01
"""Range noise of the module's simulator (m, 1-sigma)."""
QUANT_M = np.sqrt(3) * 0.0005
"""Largest error the packets' whole millimetres add to a point (m)."""
WAIT_S = 10.0
"""Generous bound on every wait for a condition (s)."""


def _wait(condition: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(f"waited {WAIT_S} s for {what}")
        time.sleep(0.01)


@pytest.fixture(scope="module")
def scene() -> LidarScene:
    return LidarScene()


@pytest.fixture(scope="module")
def sim(scene):
    """An Avia at the demo rig's lidar_front, reached by IP (its broadcasts go to a port nobody reads)."""
    with LivoxSimulator(9, scene=scene, range_noise_m=SIGMA_M) as simulator:
        yield simulator


@pytest.fixture(scope="module")
def lidar(sim):
    device = create_device({"driver": "livox", "host": "127.0.0.1", "lidar_port": sim.command_port, "data_port": 0,
                            "cmd_port": 0})
    with device:
        yield device


def _times_ns(sample: Sample) -> np.ndarray:
    return round(sample.meta["sensor_time_s"] * 1e9) + np.round(sample.meta["point_time_s"] * 1e9).astype(np.int64)


def _assert_on_rays(points: np.ndarray, truth: np.ndarray, sigma_m: float) -> None:
    """Each point lies on its true ray (within the quantisation) at the true range plus noise of ``sigma_m``."""
    assert points.shape == truth.shape and len(points) > 1000
    true_range = np.linalg.norm(truth, axis=1)
    assert (true_range > 0).all()
    ray = truth / true_range[:, None]
    along = np.einsum("ij,ij->i", points, ray)
    across = np.linalg.norm(points - along[:, None] * ray, axis=1)
    assert across.max() < QUANT_M
    error = along - true_range
    assert abs(error.mean()) < 5 * sigma_m / np.sqrt(len(error)) + 0.0005
    assert error.std() == pytest.approx(sigma_m, rel=0.1)
    assert np.abs(error).max() < 6.5 * sigma_m + QUANT_M


# --- the wire format ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("captured", [
    "AA010F0000000004D7000338BA8D0C",  # heartbeat
    "AA011000000000B809000401228D5307",  # start sampling
    "aa011900000000dc580001c0a8012152c351c352c363925b8b",  # handshake: 192.168.1.33, data 50002, cmd 50001
])
def test_control_frames_match_frames_captured_from_real_lidars(captured):
    """Frames as hosts sent them to real Livox LiDARs (openpylivox's constants and a capture), CRCs included."""
    data = bytes.fromhex(captured)
    frame = parse_frame(data)
    assert frame.cmd_type == CMD_TYPE_REQUEST and frame.cmd_set == CMD_SET_GENERAL and frame.seq == 0
    assert pack_frame(frame) == data
    if frame.cmd_id == CMD_HANDSHAKE:
        ip, data_port, cmd_port, imu_port = HANDSHAKE.unpack(frame.payload)
        assert (socket.inet_ntoa(ip), data_port, cmd_port, imu_port) == ("192.168.1.33", 50002, 50001, 50002)


def test_bad_control_frames_say_what_is_wrong():
    good = pack_frame(Frame(CMD_TYPE_REQUEST, 7, 0, 3, b""))
    cases = [
        (good[:10], "of 10 bytes"),
        (b"\x55" + good[1:], "starts with 0x55"),
        (good[:1] + b"\x02" + good[2:], "version 2; expected 1"),
        (good + b"\0", "says it has 15 bytes but 16 arrived"),
        (good[:-1] + bytes([good[-1] ^ 1]), "CRC-32"),
        (good[:5] + b"\x08" + good[6:], "preamble CRC-16"),
    ]
    for data, message in cases:
        with pytest.raises(ValueError, match=message):
            parse_frame(data)


def test_data_packets_decode_to_the_ray_cast_truth(sim):
    """Packets straight from the simulator's encoder (no network): layout, sizes, times and points."""
    packets = np.frombuffer(sim.point_packets(96 * 10, 5), np.uint8).reshape(5, -1)
    assert packets.shape[1] == packet_size(DATA_TYPE_EXTEND_CARTESIAN) == 1362
    headers = data_headers(packets)
    assert (headers["version"] == 5).all() and (headers["data_type"] == 2).all()
    stamps = packet_times_ns(headers)
    np.testing.assert_array_equal(np.diff(stamps), 96 * 4167)
    assert stamps[0] == sim.clock0_ns + 960 * 4167
    records = decode_points(packets[:, ETH_HEADER.itemsize:], DATA_TYPE_EXTEND_CARTESIAN, 4167)
    firing = 960 + records.packet * 96 + records.firing
    np.testing.assert_array_equal(records.offset_ns, records.firing * 4167)
    truth, _ = sim.truth(firing)
    assert len(records.points_m) > 300
    along = np.linalg.norm(records.points_m, axis=1) - np.linalg.norm(truth, axis=1)
    assert np.abs(along).max() < 6.5 * SIGMA_M
    imu = np.frombuffer(sim.imu_packets(0, 3), np.uint8).reshape(3, -1)
    assert imu.shape[1] == 42
    gyro, accel = decode_imu(imu[:, ETH_HEADER.itemsize:])
    np.testing.assert_allclose(accel.mean(axis=0), sim.expected_accel_m_s2(), atol=0.05)


def test_pps_gps_time_stamps_are_read_as_utc():
    header = np.zeros(1, ETH_HEADER)
    header["timestamp_type"] = 3
    # 2024-05-06 07:00 UTC, then 123456789 us into the hour
    header["timestamp"] = 24 | (5 << 8) | (6 << 16) | (7 << 24) | (123_456_789 << 32)
    assert packet_times_ns(header)[0] == 1714978800 * 10**9 + 123_456_789_000
    header["timestamp"] = 24 | (13 << 8)
    with pytest.raises(ValueError, match="holds no date"):
        packet_times_ns(header)


# --- the simulator's side of the protocol -------------------------------------------------------------------------


def test_simulator_broadcasts_acknowledges_the_handshake_and_drops_a_silent_host(scene):
    """A host made of raw sockets: the broadcast, the handshake's acknowledgement (CRCs checked by parse_frame),
    heartbeats acknowledged, and without heartbeats the LiDAR drops the host and broadcasts again."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as listener, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as cmd:
        listener.bind(("127.0.0.1", 0))
        cmd.bind(("127.0.0.1", 0))
        listener.settimeout(WAIT_S)
        cmd.settimeout(WAIT_S)
        with LivoxSimulator(listener.getsockname()[1], scene=scene, heartbeat_timeout_s=0.5) as lidar:
            data, sender = listener.recvfrom(2048)
            broadcast = parse_frame(data)
            assert (broadcast.cmd_type, broadcast.cmd_set, broadcast.cmd_id) == (CMD_TYPE_MESSAGE, 0, 0)
            assert broadcast.payload[:15] == b"1PQDH5B00100041" and broadcast.payload[16] == 7  # an Avia
            assert sender == ("127.0.0.1", lidar.command_port)
            handshake = HANDSHAKE.pack(socket.inet_aton("127.0.0.1"), 1, cmd.getsockname()[1], 1)
            cmd.sendto(pack_frame(Frame(CMD_TYPE_REQUEST, 41, 0, CMD_HANDSHAKE, handshake)), sender)
            ack = parse_frame(cmd.recv(2048))
            assert (ack.cmd_type, ack.seq, ack.cmd_id, ack.payload) == (CMD_TYPE_ACK, 41, CMD_HANDSHAKE, b"\x00")
            assert lidar.connected
            cmd.sendto(pack_frame(Frame(CMD_TYPE_REQUEST, 42, 0, CMD_HEARTBEAT, b"")), sender)
            ack = parse_frame(cmd.recv(2048))
            assert (ack.seq, ack.cmd_id, ack.payload) == (42, CMD_HEARTBEAT, b"\x00\x01\x00\x00\x00\x00\x00")
            _wait(lambda: not lidar.connected, "the LiDAR to drop the silent host")
            assert parse_frame(listener.recv(2048)).cmd_id == 0  # broadcasting again


# --- the driver through the simulator -----------------------------------------------------------------------------


def test_driver_connects_and_keeps_the_heartbeat(lidar, sim):
    assert lidar.lidar_address == ("127.0.0.1", sim.command_port)
    assert sim.connected and sim.sampling and sim.imu_on
    beats = sim.heartbeats
    _wait(lambda: sim.heartbeats >= beats + 2, "two more heartbeats")


def test_frames_match_the_ray_cast_truth_point_by_point(lidar, sim):
    frames = [lidar.read(), lidar.read()]
    for sample in frames:
        meta = sample.meta
        assert sample.points.dtype == np.float64 and sample.intensity.dtype == np.float32
        assert meta["protocol_version"] == 5 and meta["data_types"] == [2] and meta["return_mode"] == "single"
        assert meta["timestamp_type"] == "no sync" and meta["model"] == "Avia"
        assert meta["fov_deg"] == pytest.approx([70.4, 77.2]) and meta["fov_elliptical"]
        # 0.1 s of 96-point packets at 240,000 points/s (fewer only if the socket's buffer overflowed)
        assert meta["packets"] <= 251 and (meta["packets"] >= 249 or meta["lost_packets"] > 0)
        assert meta["point_time_s"].max() < 0.1 + 96 * 4167e-9
        times = _times_ns(sample)
        assert ((times - sim.clock0_ns) % 4167 == 0).all()  # every point on its firing's time
        truth, _ = sim.truth(sim.firing_of(times))
        _assert_on_rays(sample.points, truth, SIGMA_M)
        assert 0 < sample.intensity.min() and sample.intensity.max() <= 255
    assert frames[1].meta["frame_index"] == frames[0].meta["frame_index"] + 1
    gap = frames[1].meta["sensor_time_s"] - frames[0].meta["sensor_time_s"]
    assert gap == pytest.approx(0.1, abs=2 * 96 * 4167e-9)


def test_built_in_imu_reads_the_simulated_rate_and_gravity(lidar, sim):
    gyro, accel = [], []
    while sum(len(g) for g in gyro) < 100:
        sample = lidar.read()
        assert sample.imu is not None
        gyro.append(sample.imu.gyro_rad_s)
        accel.append(sample.imu.accel_m_s2)
        assert (np.diff(sample.imu.t_s) > 0).all()
    gyro, accel = np.concatenate(gyro), np.concatenate(accel)
    n = len(gyro)
    np.testing.assert_allclose(gyro.mean(axis=0), sim.gyro_bias_rad_s, atol=5 * sim.gyro_noise_rad_s / np.sqrt(n))
    np.testing.assert_allclose(accel.mean(axis=0), sim.expected_accel_m_s2(),
                               atol=5 * sim.accel_noise_g * STANDARD_GRAVITY_M_S2 / np.sqrt(n))
    assert np.linalg.norm(accel.mean(axis=0)) == pytest.approx(STANDARD_GRAVITY_M_S2, abs=0.01)  # g -> m/s²


def test_accumulated_cloud_matches_the_truth_and_coverage_grows(lidar, sim, scene):
    lidar.read()  # what queued while the tests before computed (the socket buffer may have overflowed)
    short, cloud, long = (read_accumulated(lidar, seconds) for seconds in (0.1, 0.5, 1.0))  # back to back
    assert cloud.integration_s == 0.5 and cloud.frames >= 5
    # the window's returns only (up to the last 400 us packet; less when a starved machine lost packets)
    assert cloud.time_s.min() == 0 and 0.4 < cloud.time_s.max() < 0.5
    # every point: on the surface it was cast at, within the range noise
    base = transform_points(sim.T_base_lidar, cloud.points)
    off = scene.distance_to_mesh(base)
    assert np.percentile(off, 99) < 2.6 * SIGMA_M and off.max() < 6.5 * SIGMA_M + QUANT_M
    coverage = cloud.coverage
    assert coverage.counts.shape == (155, 141)
    assert coverage.counts.sum() + coverage.beyond_grid == len(cloud.points)
    assert coverage.outside < 0.001 * len(cloud.points)  # quantisation along the edge
    # non-repetitive: the pattern keeps filling the field of view, up to the part where the rays leave the yard
    assert 0.3 < short.coverage.share < coverage.share - 0.2
    assert long.coverage.share > short.coverage.share + 0.2 and long.coverage.share > 0.8


def test_dual_return_and_an_unknown_protocol_version_through_host_sim():
    """``host="sim"``: discovery by broadcast; dual return (type 4); then packets of protocol version 6."""
    device = create_device({"driver": "livox", "host": "sim", "return_mode": "dual", "imu": False})
    with device:
        sim = device.simulator
        assert device.broadcast_code == sim.broadcast_code and device.lidar_address[1] == sim.command_port
        sample = device.read()
        assert sample.meta["data_types"] == [DATA_TYPE_DUAL_EXTEND_CARTESIAN] and sample.meta["return_mode"] == "dual"
        assert sample.imu is None and sample.meta["packets"] <= 501  # 0.1 s of packets of 48 firings
        second = sample.meta["return_index"] == 1
        assert 0.05 < second.mean() < 0.5  # poles and boxes in front of the walls
        times = _times_ns(sample)
        first_truth, second_truth = sim.truth(sim.firing_of(times))
        _assert_on_rays(sample.points[~second], first_truth[~second], sim.range_noise_m)
        assert (np.linalg.norm(sample.points[second], axis=1)
                > np.linalg.norm(first_truth[second], axis=1) + 0.02).mean() > 0.95  # behind the first return
        assert np.abs(np.linalg.norm(sample.points[second], axis=1)
                      - np.linalg.norm(second_truth[second], axis=1)).max() < 6.5 * sim.range_noise_m + QUANT_M
        sim.protocol_version = 6
        with pytest.raises(DeviceError, match=r"protocol version 6; expected 5 \(Livox SDK 1"):
            for _ in range(20):
                device.read()


def test_dropped_heartbeat_acks_are_a_disconnection(scene):
    with LivoxSimulator(9, scene=scene) as sim:
        device = create_device({"driver": "livox", "host": "127.0.0.1", "lidar_port": sim.command_port,
                                "data_port": 0, "cmd_port": 0, "stream": "imu", "timeout_s": 1.0})
        with device:
            sample = device.read()
            assert 15 <= len(sample.imu.t_s) <= 21 and sample.points is None  # 0.1 s at 200 Hz
            sim.drop_heartbeat_acks = True  # the data keeps flowing
            deadline = time.monotonic() + WAIT_S
            with pytest.raises(DeviceDisconnected, match="has not acknowledged a heartbeat for 1 s"):
                while time.monotonic() < deadline:
                    device.read()


def test_a_silent_sensor_is_a_disconnection(scene):
    with LivoxSimulator(9, scene=scene) as sim:
        device = create_device({"driver": "livox", "host": "127.0.0.1", "lidar_port": sim.command_port,
                                "data_port": 0, "cmd_port": 0, "timeout_s": 0.5})
        with device:
            device.read()
            sim.unplug()
            deadline = time.monotonic() + WAIT_S
            with pytest.raises(DeviceDisconnected, match=r"has not acknowledged a heartbeat|no Livox data packets"):
                while time.monotonic() < deadline:
                    device.read()


def test_no_lidar_answering_is_a_clear_error(scene):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as nobody:
        nobody.bind(("127.0.0.1", 0))
        device = create_device({"driver": "livox", "host": "127.0.0.1", "lidar_port": nobody.getsockname()[1],
                                "data_port": 0, "cmd_port": 0})
        with pytest.raises(DeviceError, match=r"did not acknowledge the handshake command \(3 tries of 0.5 s\)"):
            device.open()
        device.close()


@pytest.mark.parametrize("settings, message", [
    ({"frame_time_s": 0}, r"frame_time_s must be a number of seconds in \(0, 1\], not 0"),
    ({"frame_time_s": 2.0}, r"frame_time_s .* not 2.0"),
    ({"frame_time_s": float("nan")}, "not nan"),
    ({"frame_time_s": "0.1"}, "not '0.1'"),
    ({"frame_time_s": True}, "not True"),
    ({"timeout_s": -1}, "timeout_s must be"),
    ({"model": "Mid-360"}, r"unknown Livox model 'Mid-360'; supported \(Livox SDK 1\): Avia, Horizon"),
    ({"stream": "both"}, "stream must be 'points' or 'imu'"),
    ({"return_mode": "triple"}, "return_mode must be one of first, strongest, dual"),
])
def test_bad_settings_are_refused(settings, message):
    with pytest.raises(DeviceError, match=message):
        create_device({"driver": "livox", **settings})
    with pytest.raises(InputError, match=message):
        check_settings({"driver": "livox", **settings})


# --- accumulation and coverage ------------------------------------------------------------------------------------


def test_coverage_cells_and_integration_window():
    fov = FieldOfView(np.radians(10), np.radians(4))
    directions = np.radians([[4.9, 1.9], [-4.9, -1.9], [0.1, 0.1], [6.0, 0.0]])  # azimuth, elevation
    points = 3 * np.column_stack([np.cos(directions[:, 1]) * np.cos(directions[:, 0]),
                                  np.cos(directions[:, 1]) * np.sin(directions[:, 0]), np.sin(directions[:, 1])])
    coverage = coverage_of(points, fov, np.radians(1.0))
    assert coverage.counts.shape == (4, 10)
    assert coverage.counts[0, 0] == 1 and coverage.counts[3, 9] == 1 and coverage.counts[1, 4] == 1  # top left...
    assert coverage.share == pytest.approx(3 / 40)
    assert coverage_of(points, LIVOX_FOV["Avia"]).inside.sum() < 155 * 141 * 0.8  # an ellipse
    accumulator = CloudAccumulator(0.25, fov, np.radians(1.0))
    assert not accumulator.add(points[:2], np.array([10.0, 10.1]))
    assert accumulator.add(points[2:], np.array([10.2, 10.3]))  # past the window: complete, and left out
    cloud = accumulator.cloud()
    assert len(cloud.points) == 3 and cloud.frames == 2
    np.testing.assert_allclose(cloud.time_s, [0.0, 0.1, 0.2])


@pytest.mark.parametrize("integration_s", [0, -1, 61, float("nan"), "1", None])
def test_bad_integration_time_is_refused(integration_s, lidar):
    with pytest.raises(InputError, match="integration time must be a number of seconds in"):
        read_accumulated(lidar, integration_s)


def test_simulated_patterns_fill_their_fields_of_view():
    for name, pattern in PATTERNS.items():
        directions = pattern.directions(np.arange(0, 240_000, 3))
        coverage = coverage_of(directions, pattern.fov)
        assert coverage.share > 0.97, name
        assert coverage.outside == 0, name
