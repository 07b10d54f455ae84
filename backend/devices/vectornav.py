"""VectorNav VN-100 IMU over its serial binary protocol (the disaster-response robot's IMU).

The VN-100 sends binary output messages when configured for them (register 75, ``$VNWRG,75,...``; set once with
VectorNav's Control Center). The driver reads the message of output group 1 (common) with the fields TimeStartup,
AngularRate and Accel (group byte ``0x01``, field mask ``0x0121``)::

    0xFA | 0x01 | 0x21 0x01 | u64 time (ns since power-on) | 3 x f32 rate (rad/s) | 3 x f32 accel (m/s²) | u16 CRC

little-endian, the CRC (CRC-16-CCITT as VectorNav computes it, big-endian) over everything after the sync byte, so
that the CRC over the message with its CRC is zero. Messages with a bad CRC are skipped and counted, as are bytes
between messages.

Robustness: bytes that never form a valid message for ``no_data_timeout_s`` (a wrong baud rate looks like that) are a
:class:`DeviceError` naming the baud rate; a port that fails or vanishes (unplugged) is a
:class:`DeviceDisconnected`, after the samples already parsed are returned. ``port="sim"`` starts the simulated
VN-100 registered as ``"vn100"`` on a pty.
"""

from __future__ import annotations

import struct
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import serial

from backend.core.imu import ImuSamples
from backend.devices.base import (
    CaptureDevice,
    DeviceDisconnected,
    DeviceError,
    Sample,
    register_driver,
    start_simulator,
)

SYNC = 0xFA
HEADER = bytes([0x01, 0x21, 0x01])
"""Group 1 (common), fields TimeStartup (bit 0), AngularRate (bit 5), Accel (bit 8)."""
PAYLOAD = struct.Struct("<Q6f")
MESSAGE_BYTES = 1 + len(HEADER) + PAYLOAD.size + 2


def vectornav_crc(data: bytes) -> int:
    """VectorNav's CRC-16-CCITT of ``data`` (its manual's ``calculateCRC``)."""
    crc = 0
    for byte in data:
        crc = ((crc >> 8) | (crc << 8)) & 0xFFFF
        crc ^= byte
        crc ^= (crc & 0xFF) >> 4
        crc ^= (crc << 12) & 0xFFFF
        crc ^= ((crc & 0xFF) << 5) & 0xFFFF
    return crc


@dataclass
class VectorNavParser:
    """Turns the byte stream into samples; counts what it skips."""

    bad_checksums: int = 0
    skipped_bytes: int = 0
    messages: int = 0
    _buffer: bytearray = field(default_factory=bytearray)

    def feed(self, data: bytes) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """The ``(time_ns, rate (3,) rad/s, accel (3,) m/s²)`` of every whole, valid message in ``data`` (and what
        earlier calls left over)."""
        self._buffer += data
        out = []
        while True:
            start = self._buffer.find(bytes([SYNC]) + HEADER)
            if start < 0:
                keep = min(len(self._buffer), len(HEADER))  # a header may be cut at the end
                self.skipped_bytes += len(self._buffer) - keep
                del self._buffer[: len(self._buffer) - keep]
                return out
            self.skipped_bytes += start
            del self._buffer[:start]
            if len(self._buffer) < MESSAGE_BYTES:
                return out
            message = bytes(self._buffer[1:MESSAGE_BYTES])
            if vectornav_crc(message) != 0:
                self.bad_checksums += 1
                del self._buffer[:1]  # look for the next sync after this one
                continue
            del self._buffer[:MESSAGE_BYTES]
            self.messages += 1
            time_ns, *values = PAYLOAD.unpack_from(message, len(HEADER))
            out.append((time_ns, np.array(values[:3]), np.array(values[3:])))


@register_driver
class VN100Serial(CaptureDevice):
    """A VectorNav VN-100 on a serial port; :meth:`read` returns ``batch_s`` of samples as one :class:`Sample`
    (its ``imu``: times in s since the IMU's power-on; ``meta``: ``bad_checksums``, ``skipped_bytes``, ``port``)."""

    driver = "vn100"

    def __init__(self, port: str, baudrate: int = 115200, batch_s: float = 0.1, no_data_timeout_s: float = 2.0):
        """Settings as stored in the rig.

        Args:
            port: serial device (``/dev/ttyUSB0``) or ``"sim"`` for the built-in simulator.
            baudrate: the VN-100's serial rate (115200 from the factory; up to 921600).
            batch_s: IMU time (s) each :meth:`read` returns.
            no_data_timeout_s: how long without a valid message before giving up (s).
        """
        self.port, self.baudrate = str(port), int(baudrate)
        self.batch_s, self.no_data_timeout_s = float(batch_s), float(no_data_timeout_s)
        self.parser = VectorNavParser()
        self._serial: serial.Serial | None = None
        self._sim: Any = None
        self._path = self.port
        self._pending: list[tuple[int, np.ndarray, np.ndarray]] = []

    @property
    def simulator(self) -> Any:
        """The built-in simulator while open with ``port="sim"`` (tests unplug it), else None."""
        return self._sim

    def describe(self) -> str:
        return f"vn100 {self.port} @{self.baudrate}"

    def open(self) -> None:
        """Open the port and wait for the first valid message (:class:`DeviceError` naming the baud rate if none)."""
        if self.port == "sim":
            self._sim = start_simulator("vn100", self.describe())
            self._path = self._sim.port
        try:
            self._serial = serial.Serial(self._path, self.baudrate, timeout=0.05)
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise DeviceError(f"cannot open serial port {self._path}: {exc}", self.describe()) from None
        try:
            self._wait_for(1)
        except DeviceError:
            self.close()
            raise

    def read(self) -> Sample:
        """The next ``batch_s`` of samples."""
        if self._serial is None and not self._pending:
            raise DeviceDisconnected(f"{self._path} is not open", self.describe())
        try:
            while not self._pending or self._pending[-1][0] - self._pending[0][0] < self.batch_s * 1e9:
                self._wait_for(len(self._pending) + 1)
        except DeviceDisconnected:
            if not self._pending:
                raise
        batch, self._pending = self._pending, []
        t_s = np.array([b[0] for b in batch]) * 1e-9
        imu = ImuSamples(t_s, np.array([b[1] for b in batch]), np.array([b[2] for b in batch]))
        return Sample(timestamp_s=float(t_s[0]), imu=imu,
                      meta={"bad_checksums": self.parser.bad_checksums, "skipped_bytes": self.parser.skipped_bytes,
                            "port": self.port, "samples": len(batch)})

    def close(self) -> None:
        if self._serial is not None:
            try:
                self._serial.close()
            except (serial.SerialException, OSError):
                pass
            self._serial = None
        if self._sim is not None:
            self._sim.stop()
            self._sim = None

    def _wait_for(self, count: int) -> None:
        """Read until ``count`` samples are pending; :class:`DeviceError` after ``no_data_timeout_s`` without a
        valid message, :class:`DeviceDisconnected` when the port fails."""
        last_valid = time.monotonic()
        while len(self._pending) < count:
            try:
                data = self._serial.read(4096) if self._serial is not None else None
            except (serial.SerialException, OSError, TypeError) as exc:
                raise DeviceDisconnected(f"{self._path} failed (unplugged?): {exc}", self.describe()) from None
            if data is None:
                raise DeviceDisconnected(f"{self._path} is closed", self.describe())
            parsed = self.parser.feed(data)
            if parsed:
                self._pending.extend(parsed)
                last_valid = time.monotonic()
            elif time.monotonic() - last_valid > self.no_data_timeout_s:
                heard = "bytes but no valid message" if self.parser.skipped_bytes else "nothing"
                raise DeviceError(f"{heard} from {self._path} in {self.no_data_timeout_s:g} s: check the baud rate "
                                  f"({self.baudrate}) and that binary output 1 (TimeStartup, AngularRate, Accel) is "
                                  "on", self.describe())
