"""Velodyne VLP-16: the byte-level and UDP simulators, the live UDP driver (127.0.0.1 only) and the pcap driver."""

from __future__ import annotations

import socket
import struct
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import velodyne_decoder as vd

from backend.core.errors import InputError
from backend.core.transforms import transform_points
from backend.devices.base import DeviceDisconnected, DeviceError, Sample, create_device
from backend.sim.demo_rig import demo_rig
from backend.sim.lidar_scene import LABELS, ROOM_X_M, ROOM_Y_M, LidarScene, label_reflectivity
from backend.sim.velodyne_packets import (
    DISTANCE_UNIT_M,
    PACKET_SIZE,
    VLP16_ELEVATION_DEG,
    VLP16_VERTICAL_OFFSET_M,
    encode_vlp16_packets,
    simulate_vlp16_scan,
    write_pcap,
)
from backend.sim.velodyne_udp import Vlp16UdpSimulator

TOL_M = 0.002 + DISTANCE_UNIT_M / 2
"""Decoded vs true points: 2 mm (azimuth rounding, float32) plus half a range quantum."""
T_BASE_LIDAR = demo_rig().T_root_frame("lidar_top")
"""Where the simulators put the VLP-16 by default: the demo rig's lidar_top (m, into base_link)."""


@pytest.fixture(scope="module")
def sim():
    """Three turns of the shared yard from lidar_top at 600 rpm (227 packets)."""
    return simulate_vlp16_scan(n_rotations=3, timestamp_us=3_599_900_000)  # the stamp wraps at the hour


@pytest.fixture(scope="module")
def scene() -> LidarScene:
    return LidarScene()


def _decode_all(packets: list[bytes]) -> np.ndarray:
    decoder = vd.ScanDecoder(vd.Config(model=vd.Model.VLP16))
    vector = vd.PacketVector()
    for i, packet in enumerate(packets):
        vector.append(vd.VelodynePacket(1000.0 + i * 0.001327, packet))
    return np.asarray(decoder.decode(vector)[1], dtype=np.float64)


def _assert_matches_truth(sample: Sample, sim, first_packet: int) -> None:
    truth, refl, _ = sim.truth(first_packet, sample.meta["packets"])
    assert sample.points.shape == truth.shape and sample.points.dtype == np.float64
    assert np.abs(sample.points - truth).max() < TOL_M
    assert sample.intensity.dtype == np.float32
    np.testing.assert_array_equal(sample.intensity, refl)


def _assert_on_scene(points: np.ndarray, scene: LidarScene, T_base_lidar: np.ndarray = T_BASE_LIDAR) -> None:
    """Every point (sensor frame, m) lies on the yard's surfaces, and the walls are where they should be."""
    base = transform_points(T_base_lidar, points)
    off = scene.distance_to_mesh(base)
    assert np.percentile(off, 99) < TOL_M and off.max() < 2 * TOL_M  # the mesh distance is float32
    level = np.abs(base[:, 2] - T_base_lidar[2, 3]) < 0.3
    ahead = level & (np.abs(base[:, 1]) < 0.2) & (base[:, 0] > 0)
    behind = level & (np.abs(base[:, 1]) < 0.2) & (base[:, 0] < 0)
    left = level & (np.abs(base[:, 0]) < 0.2) & (base[:, 1] > 0)
    right = level & (np.abs(base[:, 0]) < 0.2) & (base[:, 1] < 0)
    assert np.median(base[ahead, 0]) == pytest.approx(ROOM_X_M[1], abs=TOL_M)
    assert np.median(base[behind, 0]) == pytest.approx(ROOM_X_M[0], abs=TOL_M)
    assert np.median(base[left, 1]) == pytest.approx(ROOM_Y_M[1], abs=TOL_M)
    assert np.median(base[right, 1]) == pytest.approx(ROOM_Y_M[0], abs=TOL_M)
    assert np.sum(np.abs(base[:, 2]) < TOL_M) > 1000  # the floor, at base z = 0


# --- packets ------------------------------------------------------------------------------------------------------


def test_packet_bytes_follow_the_vlp16_layout():
    ranges = np.full((30, 16), 4.0)
    ranges[1, 3] = 0.0
    az = np.arange(30) * 0.2 + 359.0
    packets = encode_vlp16_packets(ranges, az, reflectivity=77, timestamp_us=123_456)
    assert len(packets) == 2 and all(len(p) == PACKET_SIZE for p in packets)  # 24 columns + 6 padded
    p = packets[0]
    for block in range(12):
        flag, azimuth = struct.unpack_from("<HH", p, block * 100)
        assert flag == 0xEEFF and p[block * 100:block * 100 + 2] == b"\xff\xee"
        assert azimuth == round((359.0 + block * 0.4) * 100) % 36000  # wraps past 360
    distance, refl = struct.unpack_from("<HB", p, 4)
    assert distance == 2000 and refl == 77  # 4 m in 2 mm units
    assert struct.unpack_from("<H", p, 4 + 3 * (16 + 3))[0] == 0  # column 1 (second firing), channel 3
    assert struct.unpack_from("<IBB", p, 1200) == (123_456, 0x37, 0x22)
    assert struct.unpack_from("<I", packets[1], 1200)[0] == 123_456 + 1327
    assert struct.unpack_from("<H", packets[1], 4 + 6 * 3 * 32)[0] == 0  # padded columns have no return


def test_decoded_frame_is_x_forward_y_left_z_up():
    """Azimuth grows clockwise seen from above: a shot at 90 deg lands on -y (right)."""
    az = np.full(24, 90.0)
    packets = encode_vlp16_packets(np.full((24, 16), 5.0), az)
    points = _decode_all(packets)
    first = points[:16]  # one column, channel order
    w = np.radians(VLP16_ELEVATION_DEG)
    np.testing.assert_allclose(first[:, 0], 0.0, atol=2e-3)
    np.testing.assert_allclose(first[:, 1], -5.0 * np.cos(w), atol=1e-4)
    np.testing.assert_allclose(first[:, 2], 5.0 * np.sin(w) + VLP16_VERTICAL_OFFSET_M, atol=1e-4)
    np.testing.assert_array_equal(first[:, 6], np.argsort(np.argsort(VLP16_ELEVATION_DEG)))  # ring by elevation


@pytest.mark.parametrize("rpm, start_deg, noise", [(600, 0.0, 0.0), (1200, 123.45, 0.01), (300, 359.9, 0.0)])
def test_simulated_packets_round_trip_through_velodyne_decoder(rpm, start_deg, noise, scene):
    sim = simulate_vlp16_scan(rpm=rpm, start_azimuth_deg=start_deg, range_noise_m=noise, seed=3)
    assert len(sim.packets) == int(np.ceil(sim.packets_per_rotation))
    decoded = _decode_all(sim.packets)
    truth, refl, ring = sim.truth()
    assert decoded.shape[0] == truth.shape[0] == np.count_nonzero(sim.ranges_m)
    err = np.linalg.norm(decoded[:, :3] - truth, axis=1)
    assert err.max() < TOL_M
    np.testing.assert_array_equal(decoded[:, 3], refl)
    np.testing.assert_array_equal(decoded[:, 6], ring)
    if noise == 0:
        _assert_on_scene(decoded[:, :3], scene)
    # every kind of surface in the yard is seen, each with its own reflectivity; some upward beams
    # pass over the 3 m walls in the far corners (no return)
    labels = sim.labels[sim.ranges_m > 0]
    assert {LABELS[name] for name in ("floor", "wall", "box", "pole", "ramp", "board")} <= set(labels.tolist())
    np.testing.assert_array_equal(decoded[:, 3], np.round(label_reflectivity(labels)))
    assert decoded[labels == LABELS["board"], 3].min() > decoded[labels != LABELS["board"], 3].max()
    assert np.all(sim.labels[sim.ranges_m == 0] == 0) and np.count_nonzero(sim.ranges_m == 0) > 100


# --- live UDP -----------------------------------------------------------------------------------------------------


def _read_until_disconnected(device, match: str) -> None:
    """After the sender is unplugged: read the scans still on the way, then the DeviceDisconnected (``match``,
    whose message states the silence the driver waited; the wall time is not asserted: a loaded machine reads the
    buffered scans late)."""
    with pytest.raises(DeviceDisconnected, match=match):
        for _ in range(10):
            device.read()


def test_live_udp_scans_match_ground_truth(scene):
    device = create_device({"driver": "velodyne", "port": 0, "timeout_s": 0.4})
    with device:
        port = device.bound_port
        assert port and device.describe().endswith(f"127.0.0.1:{port}")
        with Vlp16UdpSimulator(port, garbage_every=10) as sender:  # real rate: ~10 scans/s
            scans = [device.read(), device.read()]
            sender.unplug()  # the turn in flight never completes, then silence
            _read_until_disconnected(device, rf"no Velodyne packets on udp port {port} for 0.4 s — check the "
                                             r"sensor's IP/port and that nothing else is bound")
        turn = sender.turn
        assert len(turn.packets) == 75 and sender.rpm == pytest.approx(602.8, abs=0.1)
        for index, scan in enumerate(scans):
            assert scan.meta["scan_index"] == index and scan.meta["port"] == port
            assert scan.meta["packets"] == 75 and scan.meta["complete"]
            assert scan.meta["sender"].startswith("127.0.0.1:")
            _assert_matches_truth(scan, turn, 0)  # the receiver was first: every scan is the turn from azimuth 0
            _assert_on_scene(scan.points, scene)
        assert scans[1].timestamp_s > scans[0].timestamp_s > time.time() - 60
        period_s = 75 * 1327.104e-6
        assert (scans[1].meta["sensor_time_s"] - scans[0].meta["sensor_time_s"]) % 3600 == pytest.approx(period_s,
                                                                                                         abs=2e-6)
        assert scans[1].meta["malformed"] >= 3 * 15


@pytest.mark.slow
def test_simulated_vlp16_is_selectable_as_host_sim(scene):
    device = create_device({"driver": "velodyne", "host": "sim", "timeout_s": 0.5})
    with device:
        port = device.bound_port
        assert device.describe() == f"velodyne VLP-16 sim lidar_top udp 127.0.0.1:{port}"
        scans = [device.read() for _ in range(6)]
        for scan in scans:
            assert scan.meta["complete"] and scan.meta["packets"] == 75 and scan.meta["malformed"] == 0
            azimuth = np.degrees(np.arctan2(scan.points[:, 1], scan.points[:, 0]))
            assert np.histogram(azimuth, bins=360, range=(-180, 180))[0].min() > 0  # a full turn
            _assert_on_scene(scan.points, scene)
        # The real rate, read off the packets' own clock (the host's clock of arrival is not: a loaded machine
        # delays some scans and then reads several at once).
        periods_s = np.diff([scan.meta["sensor_time_s"] for scan in scans]) % 3600
        np.testing.assert_allclose(1 / periods_s, 1 / (75 * 1327.104e-6), atol=0.01)  # 10.05 scans/s
        device.simulator.unplug()
        _read_until_disconnected(device, rf"^velodyne VLP-16 sim lidar_top udp 127.0.0.1:{port}: "
                                         r"no Velodyne packets")
        device.simulator.replug()
        again = device.read()
        assert again.meta["complete"] and again.meta["packets"] == 75
        simulator = device.simulator
    assert device.simulator is None and simulator.packets_sent > 0
    packets_sent = simulator.packets_sent
    time.sleep(0.05)
    assert simulator.packets_sent == packets_sent  # close() stopped the sender

    T_base_front = demo_rig().T_root_frame("lidar_front")
    with create_device({"driver": "velodyne", "host": "sim", "sim_sensor": "lidar_front"}) as front:
        points = front.read().points
    off = scene.distance_to_mesh(transform_points(T_base_front, points))
    assert np.percentile(off, 99) < TOL_M
    with pytest.raises(DeviceError, match=r"no simulated 3D LiDAR named 'cam_front' in the demo rig; available: "
                                          r"\[.*'lidar_front'"):
        create_device({"driver": "velodyne", "host": "sim", "sim_sensor": "cam_front"}).open()


def test_live_udp_silence_and_garbage_only():
    device = create_device({"driver": "velodyne", "port": 0, "timeout_s": 0.3})
    with device:
        with pytest.raises(DeviceDisconnected, match="no Velodyne packets on udp port"):
            device.read()
        stop = threading.Event()

        def garbage() -> None:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
                while not stop.is_set():
                    sock.sendto(b"hello", ("127.0.0.1", device.bound_port))
                    time.sleep(0.01)

        thread = threading.Thread(target=garbage, daemon=True)
        thread.start()
        try:
            with pytest.raises(DeviceDisconnected, match=r"malformed datagrams were ignored"):
                device.read()  # garbage does not keep the device alive
        finally:
            stop.set()
            thread.join()
    device.close()  # twice is fine


def test_udp_port_taken_is_a_clear_device_error():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as holder:
        holder.bind(("127.0.0.1", 0))
        port = holder.getsockname()[1]
        device = create_device({"driver": "velodyne", "port": port})
        with pytest.raises(DeviceError, match=rf"cannot bind udp 127.0.0.1:{port}.*holds it"):
            device.open()


def test_unknown_model_and_wrong_product():
    with pytest.raises(DeviceError, match="unknown Velodyne model 'VLP-99'"):
        create_device({"driver": "velodyne", "port": 0, "model": "VLP-99"}).open()
    device = create_device({"driver": "velodyne", "port": 0, "model": "VLP-32C", "timeout_s": 1.0})
    with device:
        with Vlp16UdpSimulator(device.bound_port), pytest.raises(DeviceError,
                                                                 match=r"come from a VLP-16 .* set up as VLP-32C"):
            device.read()


# --- pcap ---------------------------------------------------------------------------------------------------------


def test_pcap_replays_the_same_scans(sim, tmp_path: Path):
    # position packets (512 bytes to port 8308) are interleaved, as in a real capture
    items, stamps = [], []
    for i, packet in enumerate(sim.packets):
        items.append(packet)
        stamps.append(1_700_000_000 + i * 1327.104e-6)
        if i % 50 == 0:
            items.append((8308, b"\x00" * 512))
            stamps.append(stamps[-1] + 1e-4)
    path = write_pcap(tmp_path / "vlp16.pcap", items, timestamps_s=stamps)
    device = create_device({"driver": "velodyne_pcap", "path": str(path)})
    with device:
        scans = [device.read(), device.read()]
        with pytest.raises(DeviceDisconnected, match="end of recording after 2 scans"):
            device.read()  # the third turn is incomplete: dropped
    first = 0
    for index, scan in enumerate(scans):
        assert scan.meta["scan_index"] == index and scan.meta["source"] == "vlp16.pcap"
        assert scan.meta["complete"] and scan.meta["malformed"] == 0
        _assert_matches_truth(scan, sim, first)
        first += scan.meta["packets"]
    assert scans[0].timestamp_s == pytest.approx(1_700_000_000 + (scans[0].meta["packets"] - 1) * 1327.104e-6,
                                                 abs=2e-6)
    # velodyne-decoder's own pcap reader (dpkt) accepts the file too
    clouds = [cloud for _, cloud in vd.read_pcap(str(path), vd.Config(model=vd.Model.VLP16))]
    assert sum(len(c) for c in clouds) == np.count_nonzero(sim.ranges_m)


def test_pcap_flags_scans_with_lost_packets(tmp_path: Path):
    packets = simulate_vlp16_scan(n_rotations=6).packets  # 453 packets: 6 full scans
    # two packets lost in the second turn; in the fourth a whole turn (75 packets, 358 deg) is lost,
    # which the azimuth alone cannot notice, but the sensor's clock does
    lossy = packets[:100] + packets[102:250] + packets[325:]
    device = create_device({"driver": "velodyne_pcap", "path": str(write_pcap(tmp_path / "lossy.pcap", lossy))})
    with device:
        scans = []
        with pytest.raises(DeviceDisconnected, match="after 4 scans"):  # 5 turns sent, the last one partial
            while True:
                scans.append(device.read())
    assert [s.meta["complete"] for s in scans] == [True, False, True, False]
    assert [s.meta["packets"] for s in scans] == [76, 74, 76, 76]


@pytest.mark.parametrize("cut", [24 + 8, 24 + 16 + 100, -10])
def test_truncated_pcap_is_an_input_error_naming_the_file(sim, tmp_path: Path, cut: int):
    path = write_pcap(tmp_path / "cut.pcap", sim.packets[:10])
    data = path.read_bytes()
    path.write_bytes(data[:cut])
    device = create_device({"driver": "velodyne_pcap", "path": str(path)})
    with pytest.raises(InputError, match=r"cut\.pcap is truncated at byte") as info:
        device.open()
    assert info.value.input == str(path)


def test_bad_pcap_files_are_input_errors(tmp_path: Path):
    cases = {
        "missing.pcap": None,
        "empty.pcap": b"",
        "text.pcap": b"this is not a capture at all, just some text\n",
        "new.pcap": b"\x0a\x0d\x0d\x0a" + b"\x00" * 40,
    }
    messages = {"missing.pcap": "cannot read", "empty.pcap": "is empty", "text.pcap": "is not a pcap file",
                "new.pcap": "is a pcapng file"}
    for name, content in cases.items():
        path = tmp_path / name
        if content is not None:
            path.write_bytes(content)
        with pytest.raises(InputError, match=messages[name]) as info:
            create_device({"driver": "velodyne_pcap", "path": str(path)}).open()
        assert name in info.value.message and info.value.input == str(path)
    # a valid pcap without Velodyne data
    path = write_pcap(tmp_path / "other.pcap", [(53, b"dns?")] * 5)
    device = create_device({"driver": "velodyne_pcap", "path": str(path)})
    with device, pytest.raises(InputError, match="other.pcap holds no full turn of Velodyne data packets"):
        device.read()
