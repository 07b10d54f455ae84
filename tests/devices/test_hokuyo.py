"""The Hokuyo driver (SCIP 2.0) through its byte-level simulator on 127.0.0.1: a UTM-30LX-EW over TCP."""

from __future__ import annotations

import math
import socket
import time

import numpy as np
import pytest

from backend.devices.base import DeviceDisconnected, DeviceError, create_device
from backend.devices.hokuyo import HokuyoScanner, _Link, decode, parse_message
from backend.sim.hokuyo_sim import HokuyoSimulator, HokuyoUsbSimulator

STEP_RAD = 2 * math.pi / 1440


@pytest.fixture
def sim():
    with HokuyoSimulator() as simulator:
        yield simulator


def scanner(sim: HokuyoSimulator, **settings) -> HokuyoScanner:
    device = HokuyoScanner(host=sim.host, port=sim.port, **settings)
    device.open()
    return device


class Recorded(_Link):
    """A link that hands recorded bytes out 7 at a time, as a slow serial port or a congested socket might."""

    def __init__(self, data: bytes):
        super().__init__(None)
        self.data = data

    def _receive(self) -> bytes:
        chunk, self.data = self.data[:7], self.data[7:]
        return chunk


def truth_of(sim: HokuyoSimulator, sensor_time_ms: int) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's distances (mm) and intensities of the scan it stamped ``sensor_time_ms``."""
    pose = next(T for stamp, T in sim.scan_poses if stamp == sensor_time_ms)
    return sim.true_scan(pose, sensor_time_ms)


def test_version_parameters_and_scans_match_the_scene(sim):
    device = scanner(sim)
    try:
        assert device.version["PROD"] == "SOKUIKI Sensor TOP-URG UTM-30LX-EW" and device.version["PROT"] == "SCIP 2.0"
        assert {k: device.parameters[k] for k in ("MODL", "AMIN", "AMAX", "AFRT", "ARES", "DMIN")} == {
            "MODL": "UTM-30LX-EW", "AMIN": "0", "AMAX": "1080", "AFRT": "540", "ARES": "1440", "DMIN": "23"}
        samples = [device.read() for _ in range(4)]
    finally:
        device.close()
    assert sim.commands[:4] == ["QT", "VV", "PP", "TM0"] and "ME0000108000000" in sim.commands
    for sample in samples:
        distance_mm, intensity = truth_of(sim, sample.meta["sensor_time_ms"])
        valid = distance_mm >= 23
        steps = np.flatnonzero(valid)
        assert len(sample.points) == valid.sum() > 500 and sample.meta["steps"] == 1081
        # each point at its step's angle (REP 103: counter-clockwise from x, step 540 straight ahead) and range
        angle = (steps - 540) * STEP_RAD
        expected = np.column_stack([np.cos(angle), np.sin(angle), np.zeros(len(steps))]) * distance_mm[steps, None]
        np.testing.assert_allclose(sample.points * 1000, expected, atol=1e-9)
        np.testing.assert_array_equal(sample.intensity, intensity[steps])
        assert sample.meta["model"] == "UTM-30LX-EW" and sample.meta["serial"] == "H1630567"
    # the sensor's stamps, 25 ms apart at 40 Hz, on the host's clock (measured by TM1 round trips at open)
    stamps = np.array([s.meta["sensor_time_ms"] for s in samples])
    assert np.all(np.diff(stamps) % 25 == 0) and np.all(np.diff(stamps) > 0)
    times = np.array([s.timestamp_s for s in samples])
    np.testing.assert_allclose(np.diff(times), np.diff(stamps) / 1000, atol=1e-6)
    assert abs(times[-1] - time.time()) < 5.0  # on the host's clock, not the sensor's (seconds since power-up)


def test_the_stream_is_split_wherever_the_reads_end(sim):
    """Two messages in one read, or one message in many: every scan comes out whole."""
    connection = socket.create_connection((sim.host, sim.port))
    connection.sendall(b"ME0000108000003\n")
    data = b""
    while data.count(b"\n\n") < 4:  # the immediate answer and three scans
        data += connection.recv(65536)
    connection.close()
    link = Recorded(data)
    messages = [parse_message(link.message(1.0)) for _ in range(4)]
    assert [m.status for m in messages] == ["00", "99", "99", "99"]
    assert all(len(decode(b"".join(m.lines[1:]), 3)) == 2 * 1081 for m in messages[1:])


def test_a_scan_that_fails_its_checksum_is_skipped_and_counted(sim):
    sim.corrupt_every = 2
    device = scanner(sim)
    try:
        samples = [device.read() for _ in range(4)]
    finally:
        device.close()
    assert device.bad_checksums >= 3 and sim.corrupted_sent >= 3
    for sample in samples:  # the scans it returns are whole and right
        distance_mm, _ = truth_of(sim, sample.meta["sensor_time_ms"])
        assert len(sample.points) == (distance_mm >= 23).sum()


def test_a_dropped_connection_is_reopened_and_the_stream_goes_on(sim):
    sim.drop_after_scans = 3
    device = scanner(sim, reconnect_timeout_s=30.0)
    try:
        samples = [device.read() for _ in range(7)]
    finally:
        device.close()
    assert sim.connections_dropped >= 2 and device.reconnects >= 2
    assert samples[-1].meta["reconnects"] == device.reconnects
    assert np.all(np.diff([s.timestamp_s for s in samples]) > 0)


def test_a_scanner_that_stays_away_is_a_disconnect_naming_it(sim):
    sim.drop_after_scans = 1
    device = scanner(sim, reconnect_timeout_s=1.0)
    try:
        device.read()
        sim.refuse_connections = True
        with pytest.raises(DeviceDisconnected, match=rf"lost 127\.0\.0\.1:{sim.port} .*could not reconnect within 1 s"):
            device.read()
    finally:
        device.close()


def test_an_error_status_is_named_with_its_meaning(sim):
    sim.laser_fault = True
    with pytest.raises(DeviceError, match=r"answered 'ME0000108000000' with status 01 \(the laser is not lit"):
        scanner(sim)
    assert sim.laser_on is False


def test_nothing_listening_and_bad_settings_are_named():
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with pytest.raises(DeviceError, match=rf"cannot reach the scanner at 127\.0\.0\.1:{port}"):
        HokuyoScanner(host="127.0.0.1", port=port).open()
    with pytest.raises(DeviceError, match="give the sensor's host"):
        HokuyoScanner()


def test_the_built_in_simulator_is_selectable_as_host_sim():
    with create_device({"driver": "hokuyo", "host": "sim", "intensity": False}) as device:
        sample = device.read()
        assert device.simulator is not None and device.simulator.commands[-1] == "MD0000108000000"
    assert sample.intensity is None and len(sample.points) > 500


def test_a_usb_model_over_its_serial_port():
    """The same scans from a USB-serial model (SCIP 2.0 over a pty, as over CDC-ACM), and its unplugging named."""
    with HokuyoUsbSimulator() as usb:
        device = HokuyoScanner(serial_port=usb.port, reconnect_timeout_s=1.0)
        device.open()
        try:
            samples = [device.read() for _ in range(3)]
            assert usb.port in device.describe()
            usb.unplug()
            with pytest.raises(DeviceDisconnected, match=usb.port):
                for _ in range(200):  # what was already in flight is read first
                    device.read()
        finally:
            device.close()
    assert usb.sensor.commands[:3] == ["QT", "VV", "PP"]
    for sample in samples:
        distance_mm, intensity = truth_of(usb.sensor, sample.meta["sensor_time_ms"])
        steps = np.flatnonzero(distance_mm >= 23)
        angle = (steps - 540) * STEP_RAD
        expected = np.column_stack([np.cos(angle), np.sin(angle), np.zeros(len(steps))]) * distance_mm[steps, None]
        np.testing.assert_allclose(sample.points * 1000, expected, atol=1e-9)
        np.testing.assert_array_equal(sample.intensity, intensity[steps])
