"""The VN-100 driver through the byte-level simulator on a pty: samples at 200 Hz equal to what the simulator sent,
messages with a bad CRC skipped and counted, a wrong baud rate named, an unplug reported after the samples read."""

from __future__ import annotations

import numpy as np
import pytest

from backend.devices.base import DeviceDisconnected, DeviceError, create_device
from backend.devices.vectornav import VectorNavParser, vectornav_crc
from backend.sim import devices as _simulators  # noqa: F401  (registers the "vn100" simulator)
from backend.sim.vectornav_sim import crc16_ccitt, encode_message

pytestmark = pytest.mark.slow


def test_the_two_crcs_agree_and_a_message_parses() -> None:
    data = bytes(range(256)) * 3
    assert vectornav_crc(data) == crc16_ccitt(data)
    message = encode_message(123_456_789, np.array([0.1, -0.2, 0.3]), np.array([0.5, 0.0, 9.8]))
    parser = VectorNavParser()
    (time_ns, rate, accel), = parser.feed(b"\x00\x17" + message[:10]) + parser.feed(message[10:])  # split anywhere
    assert time_ns == 123_456_789 and np.allclose(rate, [0.1, -0.2, 0.3]) and np.allclose(accel, [0.5, 0, 9.8])
    assert parser.skipped_bytes == 2


def test_samples_through_the_pty_are_the_simulators() -> None:
    with create_device({"driver": "vn100", "port": "sim", "batch_s": 0.5}) as device:
        sample = device.read()
        simulator = device.simulator
        imu = sample.imu
        assert len(imu.t_s) >= 95 and np.allclose(np.diff(imu.t_s), 0.005, atol=1e-6)  # 200 Hz, no gap
        truth = np.array([np.concatenate(simulator.truth(t)) for t in imu.t_s])
        measured = np.column_stack([imu.gyro_rad_s - simulator.gyro_bias, imu.accel_m_s2 - simulator.accel_bias])
        assert np.abs(measured - truth)[:, :3].std() < 3 * simulator.gyro_noise  # float32 on the wire, noise added
        assert np.abs(measured - truth)[:, 3:].std() < 3 * simulator.accel_noise
        simulator.corrupt_every = 7
        later = device.read()
        assert later.meta["bad_checksums"] > 0 and later.imu.t_s[0] > imu.t_s[-1]


def test_a_wrong_baud_rate_is_named() -> None:
    device = create_device({"driver": "vn100", "port": "sim", "no_data_timeout_s": 0.5})
    device.open()
    try:
        device.simulator.wrong_baud = True
        with pytest.raises(DeviceError, match=r"bytes but no valid message .* check the baud rate \(115200\)"):
            for _ in range(50):
                device.read()
    finally:
        device.close()


def test_an_unplug_returns_what_was_read_then_reports_it() -> None:
    device = create_device({"driver": "vn100", "port": "sim", "batch_s": 0.05})
    device.open()
    try:
        device.read()
        device.simulator.unplug()
        with pytest.raises(DeviceDisconnected, match="unplugged"):
            for _ in range(100):
                device.read()
    finally:
        device.close()
