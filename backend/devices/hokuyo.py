"""Hokuyo 2D laser scanners over SCIP 2.0: the UTM-30LX-EW on Ethernet (TCP port 10940) and the USB-serial models.

The protocol is Hokuyo's "Communication Protocol Specification For SCIP2.0 Standard" as the UTM-30LX-EW speaks it:

- the host sends an ASCII command line ending in LF: two letters, parameters, optionally ``;`` and a user string;
- the sensor answers with the echo of that line, a status line (two characters and a checksum), data lines (each
  followed by its checksum) and an empty line, so every message ends in ``\\n\\n``;
- a checksum character is ``(sum of the line's bytes) & 0x3F`` plus 0x30; info lines (``KEY:value;``) sum
  ``KEY:value`` only;
- numbers are written six bits a character (plus 0x30), most significant first: distances and intensities in
  three characters, the time stamp (ms, 24 bits) in four; a scan's characters run on in lines of 64.

Commands used: ``QT`` (stop, laser off), ``VV`` (vendor, product, firmware, serial), ``PP`` (model, DMIN, DMAX,
ARES, AMIN, AMAX, AFRT, SCAN), ``II`` (state), ``TM0``/``TM1``/``TM2`` (time synchronisation: the sensor's clock
against the host's), ``ME`` (continuous distance and intensity; ``MD`` for distance only). Each streamed scan comes
with status ``99``, the sensor's time stamp and one distance (and intensity) per step; step ``i`` lies at
``(i - AFRT) * 2 pi / ARES`` rad, counter-clockwise from the front (x forward, y left, z up: REP 103). A distance below
DMIN is an error code (no echo, too near, ...) and is dropped.

Why not the ``hokuyolx`` package: its receive loop reads 512-byte chunks until the buffer ends in ``\\n\\n``, so
when the next streamed scan's first bytes arrive in the same read as the last one's end (a reader a few ms behind a
40 Hz stream) two messages are parsed as one and fail their checksums; it speaks TCP only (no USB-serial models);
and its time synchronisation asks for ``%ST``, a UST-series command the UTM-30LX-EW does not have. The framing here
splits messages wherever the reads end, over a socket or a serial port alike.

``host="sim"`` starts the simulated endpoint registered as ``"hokuyo"`` (a byte-level UTM-30LX-EW on 127.0.0.1,
:func:`~backend.devices.base.start_simulator`) and reads from it.
"""

from __future__ import annotations

import socket
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import serial

from backend.devices.base import (
    CaptureDevice,
    DeviceDisconnected,
    DeviceError,
    Sample,
    register_driver,
    start_simulator,
)

DEFAULT_TCP_PORT = 10940
"""The UTM-30LX-EW's SCIP port."""
STATUS_OK = "00"
STATUS_SCAN = "99"
STATUS_MEANINGS = {
    "01": "the laser is not lit (an unstable or abnormal condition), or a parameter is wrong",
    "02": "already in that state",
    "0E": "command not defined",
    "0F": "command not supported",
    "0L": "abnormal state",
    "0M": "unstable",
    "10": "denied",
}
"""What the status codes a sensor refuses with mean (SCIP 2.0); codes 50-97 are hardware trouble."""
TIME_SYNC_SAMPLES = 5
"""TM1 round trips at open; the fastest gives the sensor clock's offset from the host's."""
TIME_WRAP_MS = 1 << 24
"""The sensor's time stamp counts milliseconds in 24 bits (4.7 h)."""


class ScipError(Exception):
    """A message that breaks the framing or a checksum (counted and skipped while streaming)."""


def checksum(data: bytes) -> int:
    """The SCIP checksum character of a line's ``data`` bytes."""
    return (sum(data) & 0x3F) + 0x30


def decode(chars: bytes, width: int) -> np.ndarray:
    """Integers of SCIP's six-bit encoding, ``width`` characters each (the characters' count must divide)."""
    codes = np.frombuffer(chars, dtype=np.uint8).astype(np.int64) - 0x30
    if codes.size % width or np.any((codes < 0) | (codes > 63)):
        raise ScipError(f"{len(chars)} characters are not {width}-character SCIP numbers")
    codes = codes.reshape(-1, width)
    value = np.zeros(len(codes), dtype=np.int64)
    for k in range(width):
        value = (value << 6) | codes[:, k]
    return value


@dataclass
class Message:
    """One sensor message: the echoed command, the status and the data lines without their checksums."""

    echo: str
    status: str
    lines: list[bytes] = field(default_factory=list)


def parse_message(raw: bytes, info: bool = False) -> Message:
    """A message's bytes (without the final empty line) as a :class:`Message`; :class:`ScipError` for a bad
    checksum or a missing status. ``info``: the answer to VV, PP or II, whose lines (``KEY:value;``) sum
    ``KEY:value`` only (a scan's data may end a line in ``;`` too, so only these are read so)."""
    lines = raw.split(b"\n")
    if len(lines) < 2 or len(lines[1]) != 3:
        raise ScipError(f"message {raw[:40]!r} has no status line")
    status = lines[1]
    if checksum(status[:2]) != status[2]:
        raise ScipError(f"status line {status!r} fails its checksum")
    data = []
    for line in lines[2:]:
        if not line:
            raise ScipError("an empty data line")
        body, mark = line[:-1], line[-1]
        if checksum(body[:-1] if info and body.endswith(b";") else body) != mark:
            raise ScipError(f"data line {line[:40]!r} fails its checksum")
        data.append(body)
    return Message(lines[0].decode("ascii", "replace"), status[:2].decode("ascii"), data)


def parse_info(message: Message) -> dict[str, str]:
    """``KEY: value`` of a VV, PP or II answer's lines (``KEY:value;``)."""
    info = {}
    for line in message.lines:
        key, _, value = line.decode("ascii", "replace").partition(":")
        info[key] = value.rstrip(";")
    return info


class _Link:
    """A byte stream to the sensor (TCP socket or serial port) split into SCIP messages."""

    def __init__(self, connection: socket.socket | serial.Serial):
        self.connection = connection
        self.buffer = b""

    def send(self, command: str) -> None:
        data = command.encode("ascii") + b"\n"
        if isinstance(self.connection, socket.socket):
            self.connection.sendall(data)
        else:
            self.connection.write(data)

    def _receive(self) -> bytes:
        """Bytes that arrived (b"" after a quiet 50 ms); ConnectionError when the sensor closed the link."""
        if isinstance(self.connection, socket.socket):
            try:
                data = self.connection.recv(65536)
            except TimeoutError:
                return b""
            if not data:
                raise ConnectionError("the sensor closed the connection")
            return data
        return self.connection.read(self.connection.in_waiting or 1)

    def message(self, timeout_s: float) -> bytes | None:
        """The next message's bytes (without its ``\\n\\n``), or None if none completes within ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while b"\n\n" not in self.buffer:
            if time.monotonic() > deadline:
                return None
            self.buffer += self._receive()
        raw, _, self.buffer = self.buffer.partition(b"\n\n")
        return raw.lstrip(b"\n")

    def close(self) -> None:
        self.connection.close()


@register_driver
class HokuyoScanner(CaptureDevice):
    """A Hokuyo 2D scanner speaking SCIP 2.0 (UTM-30LX-EW over TCP, or a USB model on ``serial_port``).

    :meth:`read` returns one scan per :class:`Sample`: ``points`` (N, 3) in the scanner frame (m, z = 0, valid
    returns only), ``intensity`` (N,) in the sensor's units (with ``intensity=True``), ``timestamp_s`` the sensor's
    time stamp on the host's clock (offset measured by TM1 round trips at open), and ``meta`` with ``scan_index``,
    ``sensor_time_ms``, ``steps``, ``bad_checksums``, ``reconnects``, ``model``, ``serial``, ``firmware`` and
    ``status``. The sensor's own parameters (PP) and version (VV) are :attr:`parameters` and :attr:`version`.

    Robustness: a scan failing a checksum is skipped and counted; a refusal (a status other than 00 or 99, such as
    ``0L`` abnormal state or ``01`` laser not lit) is a :class:`DeviceError` naming the code and its meaning; a
    dropped connection is reopened and the stream restarted until ``reconnect_timeout_s``, then
    :class:`DeviceDisconnected` is raised.
    """

    driver = "hokuyo"

    def __init__(self, host: str | None = None, port: int = DEFAULT_TCP_PORT, serial_port: str | None = None,
                 baudrate: int = 115200, intensity: bool = True, start_step: int | None = None,
                 end_step: int | None = None, max_range_m: float = 30.0, timeout_s: float = 2.0,
                 reconnect: bool = True, reconnect_timeout_s: float = 10.0):
        """Settings as stored in the rig.

        Args:
            host: the sensor's IP address (the UTM-30LX-EW ships as 192.168.0.10), or ``"sim"`` for the built-in
                simulator; give either ``host`` or ``serial_port``.
            port: its TCP port.
            serial_port: a USB model's serial device (``/dev/ttyACM0``), at ``baudrate``.
            intensity: stream distance and intensity (``ME``) rather than distance only (``MD``).
            start_step, end_step: the steps to stream (default the sensor's AMIN..AMAX: 0..1080, 270 deg).
            max_range_m: returns beyond this (m) are dropped (the sensor's own DMIN and DMAX apply too).
            timeout_s: how long to wait for an answer or a scan (s).
            reconnect, reconnect_timeout_s: reopen a dropped connection, for at most this long (s).
        """
        if (host is None) == (serial_port is None):
            raise DeviceError("give the sensor's host (TCP, or 'sim') or its serial_port, not both or neither",
                              "hokuyo")
        self.host = host
        self.port = int(port)
        self.serial_port = serial_port
        self.baudrate = int(baudrate)
        self.intensity = bool(intensity)
        self.start_step = start_step
        self.end_step = end_step
        self.max_range_m = float(max_range_m)
        self.timeout_s = float(timeout_s)
        self.reconnect = bool(reconnect)
        self.reconnect_timeout_s = float(reconnect_timeout_s)
        self.parameters: dict[str, str] = {}
        self.version: dict[str, str] = {}
        self.status = "closed"
        self.bad_checksums = 0
        self.reconnects = 0
        self._link: _Link | None = None
        self._sim: Any = None
        self._address = (host, self.port)
        self._clock_offset_s = 0.0
        self._last_stamp_ms: int | None = None
        self._wraps = 0
        self._scans = 0

    @property
    def simulator(self) -> Any:
        """The built-in simulator while open with ``host="sim"`` (tests fault it), else None."""
        return self._sim

    def describe(self) -> str:
        where = f"{self.host}:{self.port}" if self.serial_port is None else f"{self.serial_port} @{self.baudrate}"
        return f"hokuyo {where}"

    # ------------------------------------------------------------------ interface
    def open(self) -> None:
        """Connect, stop any stream, read the sensor's version and parameters, synchronise the clocks and start
        streaming; :class:`DeviceError` naming what failed."""
        if self.host == "sim":
            self._sim = start_simulator("hokuyo", self.describe())
            self._address = (self._sim.host, self._sim.port)
        try:
            self._start()
        except (OSError, serial.SerialException) as exc:
            self.close()
            raise DeviceError(f"cannot reach the scanner at {self._where()}: {exc}", self.describe()) from None
        except DeviceError:
            self.close()
            raise

    def read(self) -> Sample:
        """The next scan (blocks up to one scan period, 25 ms at 40 Hz)."""
        while True:
            if self._link is None:
                raise DeviceDisconnected(f"{self._where()} is not open", self.describe())
            try:
                raw = self._link.message(self.timeout_s)
            except (OSError, serial.SerialException) as exc:
                self._recover(f"{exc}")
                continue
            if raw is None:
                self._recover(f"no scan for {self.timeout_s:g} s")
                continue
            try:
                message = parse_message(raw)
            except ScipError:
                self.bad_checksums += 1
                continue
            if message.status == STATUS_SCAN:
                return self._sample(message)
            if message.status != STATUS_OK:
                raise self._refusal(message)

    def close(self) -> None:
        """Stop the stream, switch the laser off and disconnect (and stop the simulator). Safe twice."""
        if self._link is not None:
            try:
                self._link.send("QT")
            except (OSError, serial.SerialException):
                pass
            self._link.close()
            self._link = None
        if self._sim is not None:
            self._sim.stop()
            self._sim = None
        self.status = "closed"

    # ------------------------------------------------------------------ internals
    def _where(self) -> str:
        return self.serial_port or f"{self._address[0]}:{self._address[1]}"

    def _connect(self) -> None:
        if self.serial_port is not None:
            self._link = _Link(serial.Serial(self.serial_port, self.baudrate, timeout=0.05))
        else:
            connection = socket.create_connection(self._address, timeout=self.timeout_s)
            connection.settimeout(0.05)
            self._link = _Link(connection)

    def _start(self) -> None:
        self._connect()
        self._request("QT", STATUS_OK)
        self.version = parse_info(self._request("VV", STATUS_OK, info=True))
        self.parameters = parse_info(self._request("PP", STATUS_OK, info=True))
        self._sync_clock()
        first = int(self.parameters.get("AMIN", 0)) if self.start_step is None else self.start_step
        last = int(self.parameters.get("AMAX", 1080)) if self.end_step is None else self.end_step
        self._steps = np.arange(first, last + 1)
        self._request(f"{'ME' if self.intensity else 'MD'}{first:04d}{last:04d}00000", STATUS_OK)
        self.status = "streaming"

    def _request(self, command: str, *accepted: str, info: bool = False) -> Message:
        """Send ``command`` and return its answer (the messages before it, a stream's last scans, are skipped);
        :class:`DeviceError` if it does not come or its status is not ``accepted``."""
        self._link.send(command)
        deadline = time.monotonic() + self.timeout_s
        while (raw := self._link.message(max(deadline - time.monotonic(), 0.0))) is not None:
            if not raw.startswith(command.encode("ascii") + b"\n"):
                continue
            try:
                message = parse_message(raw, info)
            except ScipError as exc:
                raise DeviceError(f"the answer to {command} is garbled ({exc})", self.describe()) from None
            if message.status not in accepted:
                raise self._refusal(message)
            return message
        raise DeviceError(f"no answer to {command} from {self._where()} within {self.timeout_s:g} s: is it a Hokuyo "
                          "speaking SCIP 2.0 on this address?", self.describe())

    def _refusal(self, message: Message) -> DeviceError:
        code = message.status
        meaning = STATUS_MEANINGS.get(code, "hardware trouble" if code.isdigit() and 50 <= int(code) <= 97 else
                                      "an error status")
        self.status = f"refused {message.echo}: status {code}"
        return DeviceError(f"the scanner answered {message.echo!r} with status {code} ({meaning})", self.describe())

    def _sync_clock(self) -> None:
        """The sensor clock's offset from the host's (s), from the fastest of :data:`TIME_SYNC_SAMPLES` TM1 round
        trips (the sensor's stamp taken at the round trip's middle)."""
        self._request("TM0", STATUS_OK, "02")
        best = None
        for _ in range(TIME_SYNC_SAMPLES):
            sent = time.time()
            message = self._request("TM1", STATUS_OK)
            received = time.time()
            stamp_ms = int(decode(message.lines[0][:4], 4)[0])
            if best is None or received - sent < best[0]:
                best = (received - sent, (sent + received) / 2 - stamp_ms / 1000.0)
        self._request("TM2", STATUS_OK, "03")
        self._clock_offset_s = best[1]
        self._last_stamp_ms, self._wraps = None, 0

    def _host_time(self, stamp_ms: int) -> float:
        """A sensor time stamp (ms, 24 bits) on the host's clock (s), counting the wraps of the 24-bit counter."""
        if self._last_stamp_ms is not None and stamp_ms < self._last_stamp_ms - TIME_WRAP_MS // 2:
            self._wraps += 1
        self._last_stamp_ms = stamp_ms
        return (stamp_ms + self._wraps * TIME_WRAP_MS) / 1000.0 + self._clock_offset_s

    def _sample(self, message: Message) -> Sample:
        stamp_ms = int(decode(message.lines[0][:4], 4)[0])
        values = decode(b"".join(message.lines[1:]), 3)
        width = 2 if self.intensity else 1
        if values.size != width * len(self._steps):
            self.bad_checksums += 1
            raise DeviceError(f"a scan holds {values.size // width} steps where {len(self._steps)} were asked for",
                              self.describe())
        values = values.reshape(-1, width)
        distance_mm = values[:, 0]
        dmin = int(self.parameters.get("DMIN", 20))
        dmax = min(int(self.parameters.get("DMAX", 60000)), int(self.max_range_m * 1000))
        valid = (distance_mm >= dmin) & (distance_mm <= dmax)
        angle = (self._steps[valid] - int(self.parameters.get("AFRT", 540))) * 2 * np.pi / int(
            self.parameters.get("ARES", 1440))
        r = distance_mm[valid] / 1000.0
        points = np.column_stack([r * np.cos(angle), r * np.sin(angle), np.zeros(len(r))])
        self._scans += 1
        return Sample(self._host_time(stamp_ms), points=points,
                      intensity=values[valid, 1].astype(np.float32) if self.intensity else None,
                      meta={"scan_index": self._scans - 1, "sensor_time_ms": stamp_ms, "steps": len(self._steps),
                            "bad_checksums": self.bad_checksums, "reconnects": self.reconnects,
                            "model": self.parameters.get("MODL"), "serial": self.version.get("SERI"),
                            "firmware": self.version.get("FIRM"), "status": self.status})

    def _recover(self, reason: str) -> None:
        """Reconnect and restart the stream after ``reason`` until :attr:`reconnect_timeout_s`; else
        :class:`DeviceDisconnected`."""
        if self._link is not None:
            self._link.close()
            self._link = None
        if not self.reconnect:
            self.status = f"disconnected: {reason}"
            raise DeviceDisconnected(f"lost {self._where()}: {reason}", self.describe())
        deadline = time.monotonic() + self.reconnect_timeout_s
        self.status = f"reconnecting ({reason})"
        while time.monotonic() < deadline:
            try:
                self._start()
                self.reconnects += 1
                return
            except (OSError, serial.SerialException, DeviceError):
                if self._link is not None:
                    self._link.close()
                    self._link = None
                time.sleep(0.2)
        self.status = f"disconnected: {reason}"
        raise DeviceDisconnected(f"lost {self._where()} ({reason}) and could not reconnect within "
                                 f"{self.reconnect_timeout_s:g} s", self.describe())
