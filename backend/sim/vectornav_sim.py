"""A byte-level VectorNav VN-100 on a pseudo-terminal: binary output group 1 (TimeStartup, AngularRate, Accel) at
``rate_hz``, as documented in :mod:`backend.devices.vectornav`, its CRC written independently of the driver's.

The IMU turns about each axis along a sine and shakes along each (so its excitation is known), with constant biases
and white noise; :meth:`truth` gives the noiseless signals at any time. Faults, switchable while it runs:
``corrupt_every`` spoils the CRC of every n-th message, ``wrong_baud`` sends random bytes instead (what a host at
the wrong rate sees), :meth:`unplug` closes the pty.
"""

from __future__ import annotations

import struct
import time

import numpy as np

from backend.sim.pty_device import PtyDevice

GRAVITY_M_S2 = 9.80665


def crc16_ccitt(data: bytes) -> int:
    """CRC-16-CCITT (polynomial 0x1021, initial 0), bit by bit: VectorNav's checksum, computed the textbook way."""
    crc = 0
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def encode_message(time_ns: int, rate: np.ndarray, accel: np.ndarray, corrupt: bool = False) -> bytes:
    body = bytes([0x01, 0x21, 0x01]) + struct.pack("<Q6f", time_ns, *rate, *accel)
    crc = crc16_ccitt(body) ^ (0x0101 if corrupt else 0)
    return bytes([0xFA]) + body + struct.pack(">H", crc)


class VN100Simulator(PtyDevice):
    """A simulated VN-100 behind a pty; :attr:`port` is the path a driver opens."""

    def __init__(self, rate_hz: float = 200.0, seed: int = 0, gyro_noise: float = 0.002, accel_noise: float = 0.02,
                 corrupt_every: int = 0, wrong_baud: bool = False):
        super().__init__("ttyVN100")
        self.rate_hz, self.corrupt_every, self.wrong_baud = rate_hz, corrupt_every, wrong_baud
        self.gyro_noise, self.accel_noise = gyro_noise, accel_noise
        self._rng = np.random.default_rng(seed)
        self.gyro_bias = np.array([0.01, -0.02, 0.005])
        self.accel_bias = np.array([0.05, 0.03, -0.08])
        self.sent = 0
        self.corrupted_sent = 0

    def truth(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The noiseless, unbiased angular rate (rad/s) and specific force (m/s²) at ``t_s`` after power-on:
        rates along sines of 0.4-0.7 Hz, and gravity's reaction (+z) with a shake along each axis."""
        phase = 2 * np.pi * np.array([0.4, 0.55, 0.7]) * t_s
        rate = np.array([0.8, 0.6, 0.9]) * np.sin(phase)
        force = np.array([0.0, 0.0, GRAVITY_M_S2]) + np.array([1.5, 1.2, 2.0]) * np.cos(1.3 * phase)
        return rate, force

    def on_plug(self) -> None:
        self._t0 = time.monotonic()
        self._due = 0

    def serve(self) -> None:
        while not self.stopping:
            if self.read(0.002) is None:
                return
            now = time.monotonic() - self._t0
            if self.wrong_baud:
                if not self.write(self._rng.integers(0, 256, 64, dtype=np.uint8).tobytes()):
                    return
                continue
            messages = []
            while self._due <= now * self.rate_hz:
                t_s = self._due / self.rate_hz
                rate, force = self.truth(t_s)
                self.sent += 1
                corrupt = self.corrupt_every > 0 and self.sent % self.corrupt_every == 0
                self.corrupted_sent += corrupt
                messages.append(encode_message(
                    round(t_s * 1e9), rate + self.gyro_bias + self._rng.normal(0, self.gyro_noise, 3),
                    force + self.accel_bias + self._rng.normal(0, self.accel_noise, 3), corrupt))
                self._due += 1
            if messages and not self.write(b"".join(messages)):
                return
