"""YDLiDAR TG30 (TG15/TG30/TG50 and the same serial protocol family) over a serial port.

The protocol below is the one the vendor's SDK speaks (YDLIDAR/YDLidar-SDK):
``core/common/ydlidar_protocol.h`` (command bytes, ``PH``, packet structs, response header),
``core/common/ydlidar_def.h`` (``TRI_PACKHEADSIZE`` 10, ``TRI_PACKMAXNODES`` 80),
``src/YDlidarDriver.cpp`` (``parseResponseHeader``/``parseResponseScanData``/``calcuteCheckSum``/
``parseNodeFromeBuffer``: header parsing, check code, sample angles, angle correction) and
``src/CYdLidar.cpp`` (``doProcessSimple``: range units, ``reversion``/``inverted``).

Commands (host -> device), two bytes each: ``0xA5 cmd``

==========  =====================================================================
``A5 60``   start scanning (``LIDAR_CMD_SCAN``)
``A5 65``   stop scanning (``LIDAR_CMD_STOP``); the SDK sends ``A5 00`` (force stop) first
``A5 90``   get device info (``LIDAR_CMD_GET_DEVICE_INFO``)
``A5 92``   get device health (``LIDAR_CMD_GET_DEVICE_HEALTH``)
==========  =====================================================================

Responses (device -> host) start with a 7-byte header ``A5 5A`` + uint32 LE (bits 0-29 payload
size, bits 30-31 sub-type) + type byte. Start scan answers ``A5 5A 05 00 00 40 81`` (type
``0x81`` measurement) and then streams packets; device info answers ``A5 5A 14 00 00 00 04``
and 20 bytes: model (u8, TG30 = 101), firmware (u16 LE, major = high byte, minor = low byte),
hardware (u8), serial number (16 bytes, one digit per byte).

Scan packet (all multi-byte fields little-endian; 2-byte samples, i.e. no intensity, as the
TG series streams with ``intensity: false``):

======  =====  ================================================================================
offset  bytes  field
======  =====  ================================================================================
0       2      PH = ``AA 55`` (the u16 ``0x55AA``)
2       1      CT: bit 0 = 1 on the ring-start ("zero") packet that begins a 360 degree scan;
               bits 7..1 on that packet = scan frequency in 0.1 Hz (TOF firmware adds 3 Hz)
3       1      LSN: number of samples in the packet (1..80; the SDK rejects more)
4       2      FSA: bit 0 = check bit (must be 1); angle of the first sample = (FSA >> 1) / 64 deg
6       2      LSA: same for the last sample
8       2      CS: check code = XOR of every other u16 word of the packet:
               ``PH ^ (CT | LSN << 8) ^ FSA ^ LSA ^ S1 ^ ... ^ S_LSN`` (so XOR of all words = 0)
10      2*LSN  S_i: TOF (TG) -> distance in mm (firmware <= 1.2: units of 0.5 mm);
               triangle models -> distance in 0.25 mm. 0 = no return (invalid).
======  =====  ================================================================================

Sample ``i`` of a packet lies at ``FSA/64 + i * ((LSA - FSA) mod 360) / (LSN - 1)`` degrees;
TOF models get no second-stage angle correction, triangle models add
``atan(21.8 * (155.3 - d) / (155.3 * d))`` (d in mm). A scan is every sample from one
ring-start packet up to the next one.

Angle convention. The device's angle grows clockwise seen from above (the SDK's ``inverted``
flag, "is it counter clockwise", maps it with ``angle = 2 pi - angle``) and on the TG series
its 0 degree mark points backwards (``reversion``: ``angle += pi``). ``CYdLidar`` applies
reversion, then inversion; the vendor's ROS launch file for the TG series (``TG.launch``) sets
both, so with the defaults here ``theta = pi - device_angle``: our angle, counter-clockwise
from x forward, y left, z up (REP 103), as in the rest of the studio.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
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

HEADER = b"\xaa\x55"
"""Packet header ``PH`` as it appears on the wire."""
HEADER_BYTES = 10
"""``TRI_PACKHEADSIZE``: bytes before the samples."""
MAX_SAMPLES_PER_PACKET = 80
"""``TRI_PACKMAXNODES``: the SDK drops packets that claim more samples."""
ANGLE_UNITS_PER_TURN = 360 * 64
"""FSA/LSA count 1/64 degree."""

CMD_SYNC = 0xA5
CMD_STOP = 0x65
CMD_FORCE_STOP = 0x00
CMD_SCAN = 0x60
CMD_DEVICE_INFO = 0x90
ANS_SYNC = b"\xa5\x5a"
ANS_TYPE_DEVINFO = 0x04
ANS_TYPE_MEASUREMENT = 0x81
DEVICE_INFO_BYTES = 20

TOF_MODELS = {100: "TG15", 101: "TG30", 102: "TG50"}
"""``DriverInterface::YDLIDAR_TG15/TG30/TG50`` model codes."""


class _Silent(serial.SerialException):
    """The port is open but nothing at all arrived for the no-data timeout."""


@dataclass
class Scan:
    """One full 360 degree revolution, samples in the order the device measured them."""

    timestamp_s: float
    """Wall-clock time (s since the epoch) when its ring-start packet arrived."""
    angles_rad: np.ndarray
    """(N,) float64 angle of each sample (rad) in the scanner frame, counter-clockwise from x
    forward (REP 103), wrapped to [-pi, pi)."""
    ranges_m: np.ndarray
    """(N,) float64 measured range (m); 0 where the device reported no return."""
    valid: np.ndarray
    """(N,) bool: a return within the parser's [min_range_m, max_range_m]."""
    index: int = 0
    """Number of scans the parser completed before this one."""
    scan_frequency_hz: float | None = None
    """Rotation rate the device reported in the ring-start packet (Hz), if it did."""
    packets: int = 0
    """Packets that made up the scan."""

    @property
    def coverage_rad(self) -> float:
        """Angle swept from the first to the last sample (rad), about 2 pi for a full scan."""
        if len(self.angles_rad) < 2:
            return 0.0
        steps = np.diff(self.angles_rad)
        steps = (steps + np.pi) % (2 * np.pi) - np.pi  # wrap each step
        return float(np.abs(steps).sum())


def scan_to_points(scan: Scan) -> np.ndarray:
    """(N, 3) float64 points (m) of the valid samples in the scanner frame: x forward, y left, z = 0."""
    r = scan.ranges_m[scan.valid]
    a = scan.angles_rad[scan.valid]
    return np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros_like(r)])


class YdlidarParser:
    """Streaming parser: bytes in, completed 360 degree scans out.

    Resynchronises on ``AA 55`` after garbage, drops (and counts) packets whose check code is
    wrong or whose header is implausible, and keeps partial packets across :meth:`feed` calls.
    Packets before the first ring-start packet are dropped (the scan they belong to is partial).
    If a ring-start packet is lost, the scan is closed when the device angle wraps instead.
    """

    def __init__(
        self,
        lidar_type: str = "tof",
        tof_old_firmware: bool = False,
        reversion: bool = True,
        inverted: bool = True,
        min_range_m: float = 0.0,
        max_range_m: float = math.inf,
    ):
        """Args:
        lidar_type: ``"tof"`` (TG15/TG30/TG50: mm, no angle correction) or ``"triangle"``
            (G/X/S series without intensity: quarter-mm and the SDK's angle correction).
        tof_old_firmware: TOF firmware <= 1.2 reports half-millimetres (SDK
            ``isOldVersionTOFLidar``) and no +3 Hz offset in the frequency field.
        reversion: the device's 0 degree points backwards (add pi), as on the TG series.
        inverted: the device angle grows clockwise (map with 2 pi - angle), as on the TG series.
        min_range_m, max_range_m: returns outside this interval (m) are marked invalid.
        """
        if lidar_type not in ("tof", "triangle"):
            raise ValueError(f"lidar_type must be 'tof' or 'triangle', not {lidar_type!r}")
        self.lidar_type = lidar_type
        self.tof_old_firmware = tof_old_firmware
        self.reversion = reversion
        self.inverted = inverted
        self.min_range_m = min_range_m
        self.max_range_m = max_range_m
        self.packets = 0
        """Packets with a good check code."""
        self.bad_checksums = 0
        """Candidate packets (a header with plausible fields) whose check code was wrong."""
        self.skipped_bytes = 0
        """Bytes that were not part of a good packet (garbage, bad packets, command responses)."""
        self.scans = 0
        """Scans returned so far."""
        self._buf = b""
        self._cur: list[tuple[int, int, np.ndarray]] | None = None
        self._cur_t = 0.0
        self._cur_freq: float | None = None

    @property
    def range_scale_m(self) -> float:
        """Metres per distance count."""
        if self.lidar_type == "triangle":
            return 0.00025
        return 0.0005 if self.tof_old_firmware else 0.001

    def reset(self) -> None:
        """Forget buffered bytes and the scan in progress (after a reconnect); counters stay."""
        self._buf = b""
        self._cur = None

    def flush(self) -> list[Scan]:
        """End of a recording: return the scan in progress (it may not cover a full turn)."""
        return [self._finish()] if self._cur else []

    def feed(self, data: bytes, timestamp_s: float | None = None) -> list[Scan]:
        """Parse ``data`` (any split of the stream) and return the scans it completed.

        A scan is complete when the next ring-start packet arrives, so a live scan comes out
        one packet after its last sample.
        """
        now = time.time() if timestamp_s is None else timestamp_s
        buf = self._buf + bytes(data) if self._buf else bytes(data)
        n = len(buf)
        pos = 0
        out: list[Scan] = []
        while True:
            i = buf.find(HEADER, pos)
            if i < 0:
                keep = 1 if n > pos and buf[n - 1] == 0xAA else 0  # may be the first header byte
                self.skipped_bytes += n - pos - keep
                pos = n - keep
                break
            self.skipped_bytes += i - pos
            if n - i < HEADER_BYTES:
                pos = i
                break
            lsn = buf[i + 3]
            fsa = buf[i + 4] | (buf[i + 5] << 8)
            lsa = buf[i + 6] | (buf[i + 7] << 8)
            if lsn == 0 or lsn > MAX_SAMPLES_PER_PACKET or not (fsa & lsa & 1):
                self.skipped_bytes += 2  # not a packet header after all
                pos = i + 2
                continue
            end = i + HEADER_BYTES + 2 * lsn
            if end > n:
                pos = i  # wait for the rest of the packet
                break
            words = np.frombuffer(buf, dtype="<u2", count=5 + lsn, offset=i)
            if int(np.bitwise_xor.reduce(words)) != 0:
                self.bad_checksums += 1
                self.skipped_bytes += 2
                pos = i + 2  # resynchronise inside it: a corrupt LSN must not swallow good packets
                continue
            self.packets += 1
            self._on_packet(buf[i + 2], fsa >> 1, lsa >> 1, words[5:], now, out)
            pos = end
        self._buf = buf[pos:]
        return out

    def _on_packet(self, ct: int, fsa: int, lsa: int, samples: np.ndarray, now: float, out: list[Scan]) -> None:
        if ct & 0x01:  # ring start
            if self._cur:
                out.append(self._finish())
            self._cur = [(fsa, lsa, samples)]
            self._cur_t = now
            code = ct >> 1
            if code == 0:
                self._cur_freq = None
            elif self.lidar_type == "tof" and not self.tof_old_firmware:
                self._cur_freq = code / 10.0 + 3.0  # CYdLidar: scan_frequence / 10 + 3 for TOF
            else:
                self._cur_freq = code / 10.0
            return
        if self._cur is None:
            return  # before the first ring start: part of a scan we did not see begin
        last_fsa = self._cur[-1][0]
        if fsa + ANGLE_UNITS_PER_TURN // 2 < last_fsa or len(self._cur) > 4096:
            # the angle wrapped without a ring-start packet (it was lost): close the scan here
            out.append(self._finish())
            self._cur = [(fsa, lsa, samples)]
            self._cur_t = now
            self._cur_freq = None
            return
        self._cur.append((fsa, lsa, samples))

    def _finish(self) -> Scan:
        packets = self._cur or []
        self._cur = None
        lsn = np.array([len(p[2]) for p in packets], dtype=np.int64)
        fsa = np.array([p[0] for p in packets], dtype=np.float64)
        lsa = np.array([p[1] for p in packets], dtype=np.float64)
        diff = (lsa - fsa) % ANGLE_UNITS_PER_TURN
        step = np.where(lsn > 1, diff / np.maximum(lsn - 1, 1), 0.0)
        total = int(lsn.sum())
        first = np.cumsum(lsn) - lsn
        idx = np.arange(total) - np.repeat(first, lsn)
        angle_deg = (np.repeat(fsa, lsn) + np.repeat(step, lsn) * idx) / 64.0
        raw = np.concatenate([p[2] for p in packets]).astype(np.float64) if packets else np.zeros(0)
        returned = raw > 0
        if self.lidar_type == "triangle":
            d_mm = np.where(returned, raw / 4.0, 1.0)
            correction = np.degrees(np.arctan(21.8 * (155.3 - d_mm) / (155.3 * d_mm)))
            angle_deg = angle_deg + np.where(returned, correction, 0.0)
        ranges = raw * self.range_scale_m
        theta = np.radians(angle_deg)
        if self.reversion:
            theta = theta + np.pi
        if self.inverted:
            theta = -theta  # 2 pi - theta, before wrapping
        theta = (theta + np.pi) % (2 * np.pi) - np.pi
        valid = returned & (ranges >= self.min_range_m) & (ranges <= self.max_range_m)
        scan = Scan(timestamp_s=self._cur_t, angles_rad=theta, ranges_m=ranges, valid=valid, index=self.scans,
                    scan_frequency_hz=self._cur_freq, packets=len(packets))
        self.scans += 1
        return scan


def _parse_device_info(payload: bytes) -> dict[str, Any]:
    model = payload[0]
    firmware = payload[1] | (payload[2] << 8)
    return {
        "model": model,
        "model_name": TOF_MODELS.get(model, f"YD-{model}"),
        "firmware": f"{firmware >> 8}.{firmware & 0xFF}",
        "firmware_major": firmware >> 8,
        "firmware_minor": firmware & 0xFF,
        "hardware": payload[3],
        "serial": "".join(str(b & 0xFF) for b in payload[4:20]),
    }


@register_driver
class YdlidarSerial(CaptureDevice):
    """A YDLiDAR TG30 (or TG15/TG50, or a triangle model with ``lidar_type="triangle"``) on a serial port.

    :meth:`read` returns one full 360 degree scan per :class:`Sample`: ``points`` (N, 3) in the
    scanner frame (m, z = 0, valid returns only), no intensity, and ``meta`` with
    ``scan_index``, ``bad_checksums``, ``skipped_bytes``, ``port``, ``scan_frequency_hz``,
    ``coverage_deg``, ``reconnects`` and ``status``. ``port="sim"`` starts the simulated endpoint
    registered as ``"ydlidar"`` (a simulated TG30 on a pty, :func:`~backend.devices.base.start_simulator`)
    and reads from it, so the simulated scanner can be picked like any other device.

    Robustness: garbage bytes and packets with a bad check code are skipped and counted; if
    bytes arrive but no valid packet for ``no_data_timeout_s`` (a wrong baud rate looks like
    that) a :class:`DeviceError` says to check the baud rate; if the port fails or vanishes
    (unplugged) it is reopened and scanning restarted until ``reconnect_timeout_s``, then
    :class:`DeviceDisconnected` is raised. Scans already parsed are returned before any error.
    """

    driver = "ydlidar"

    def __init__(
        self,
        port: str,
        baudrate: int = 512000,
        min_range_m: float = 0.05,
        max_range_m: float = 30.0,
        reconnect: bool = True,
        reconnect_timeout_s: float = 10.0,
        no_data_timeout_s: float = 2.0,
        lidar_type: str = "tof",
        reversion: bool = True,
        inverted: bool = True,
    ):
        """Settings as stored in the rig.

        Args:
            port: serial device (``/dev/ttyUSB0``, a udev symlink such as ``/dev/ydlidar``) or
                ``"sim"`` for the built-in simulator.
            baudrate: 512000 for the TG series (230400 or 128000/115200 for others).
            min_range_m, max_range_m: returns outside this interval (m) are dropped.
            reconnect: reopen the port after an unplug instead of failing at once.
            reconnect_timeout_s: how long to keep trying to reopen (s).
            no_data_timeout_s: how long without a valid packet before giving up (s).
            lidar_type: ``"tof"`` (TG series) or ``"triangle"``.
            reversion, inverted: the SDK's flags (see the module docstring); TG defaults.
        """
        if lidar_type not in ("tof", "triangle"):
            raise DeviceError(f"lidar_type must be 'tof' or 'triangle', not {lidar_type!r}", f"ydlidar {port}")
        self.port = str(port)
        self.baudrate = int(baudrate)
        self.min_range_m = float(min_range_m)
        self.max_range_m = float(max_range_m)
        self.reconnect = bool(reconnect)
        self.reconnect_timeout_s = float(reconnect_timeout_s)
        self.no_data_timeout_s = float(no_data_timeout_s)
        self.lidar_type = lidar_type
        self.reversion = bool(reversion)
        self.inverted = bool(inverted)
        self.status = "closed"
        """One line for the UI: closed, streaming, reconnecting ..., unplugged ..., no valid packets ..."""
        self.device_info: dict[str, Any] | None = None
        self.reconnects = 0
        self._serial: serial.Serial | None = None
        self._sim: Any = None
        self._path = self.port
        self._parser = self._new_parser(False)
        self._pending: list[Scan] = []
        self._last_packet_s = 0.0
        self._bytes_since_packet = 0
        self._trouble_since: float | None = None
        self._closed = True

    # ------------------------------------------------------------------ interface
    @property
    def simulator(self) -> Any:
        """The built-in simulator (the endpoint registered as ``"ydlidar"``) while open with ``port="sim"``
        (tests unplug and replug it), else None."""
        return self._sim

    def describe(self) -> str:
        return f"ydlidar {self.port} @{self.baudrate}"

    def open(self) -> None:
        """Open the port, stop any running scan, read the device info, start scanning and wait
        for the first valid packet (:class:`DeviceError` naming the baud rate if none comes)."""
        self._closed = False
        if self.port == "sim":
            self._sim = start_simulator("ydlidar", self.describe())
            self._path = self._sim.port
        try:
            self._connect()
        except (serial.SerialException, OSError) as exc:
            self.close()
            self.status = f"cannot open {self._path}"
            raise DeviceError(f"cannot open serial port {self._path}: {exc}", self.describe()) from None
        try:
            while self._parser.packets == 0:
                self._read_chunk()
        except DeviceError:
            status = self.status
            self.close()
            self.status = status  # keep "no valid packets: check the baud rate" for the UI
            raise
        except _Silent as exc:
            self.close()
            self.status = f"no data from {self._path}: check the port and the baud rate"
            raise DeviceError(f"no data from {self._path} ({exc}): is the YDLiDAR powered and on this port? "
                              f"check the baud rate (512000 for TG30)", self.describe()) from None
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise DeviceDisconnected(f"{self._path} failed while starting the scan (unplugged?): {exc}",
                                     self.describe()) from None

    def read(self) -> Sample:
        """The next full scan (blocks about one revolution, 0.1 s at 10 Hz)."""
        if self._serial is None and not self._pending:
            raise DeviceDisconnected(f"{self._path} is not open", self.describe())
        while not self._pending:
            try:
                self._read_chunk()
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                if self._closed:  # close() from another thread while we were reading
                    raise DeviceDisconnected(f"{self._path} was closed", self.describe()) from None
                self._recover(f"serial error: {exc}")
        scan = self._pending.pop(0)
        return Sample(
            timestamp_s=scan.timestamp_s,
            points=scan_to_points(scan),
            intensity=None,
            meta={
                "scan_index": scan.index,
                "bad_checksums": self._parser.bad_checksums,
                "skipped_bytes": self._parser.skipped_bytes,
                "port": self.port,
                "scan_frequency_hz": scan.scan_frequency_hz,
                "coverage_deg": math.degrees(scan.coverage_rad),
                "n_samples": int(len(scan.ranges_m)),
                "reconnects": self.reconnects,
                "status": self.status,
            },
        )

    def close(self) -> None:
        """Stop scanning and release the port (and the simulator if ``port="sim"``). Safe twice."""
        self._closed = True
        self._disconnect(send_stop=True)
        if self._sim is not None:
            self._sim.stop()
            self._sim = None
        self.status = "closed"

    # ------------------------------------------------------------------ internals
    def _new_parser(self, old_firmware: bool) -> YdlidarParser:
        return YdlidarParser(lidar_type=self.lidar_type, tof_old_firmware=old_firmware, reversion=self.reversion,
                             inverted=self.inverted, min_range_m=self.min_range_m, max_range_m=self.max_range_m)

    def _connect(self) -> None:
        """Open the port and start a scan (raises serial.SerialException / OSError)."""
        self._serial = serial.Serial(self._path, self.baudrate, timeout=0.05, write_timeout=1.0)
        ser = self._serial
        ser.write(bytes([CMD_SYNC, CMD_FORCE_STOP]))  # as YDlidarDriver::stopScan
        time.sleep(0.005)
        ser.write(bytes([CMD_SYNC, CMD_STOP]))
        time.sleep(0.02)
        ser.reset_input_buffer()
        ser.write(bytes([CMD_SYNC, CMD_DEVICE_INFO]))
        payload = self._wait_response(ANS_TYPE_DEVINFO, DEVICE_INFO_BYTES, timeout_s=0.5)
        if payload is not None:
            self.device_info = _parse_device_info(payload)
            old = (self.device_info["model"] in TOF_MODELS and self.device_info["firmware_major"] <= 1
                   and self.device_info["firmware_minor"] <= 2)  # SDK isOldVersionTOFLidar
            if old != self._parser.tof_old_firmware:
                counters = (self._parser.bad_checksums, self._parser.skipped_bytes, self._parser.scans)
                self._parser = self._new_parser(old)
                self._parser.bad_checksums, self._parser.skipped_bytes, self._parser.scans = counters
        ser.reset_input_buffer()
        ser.write(bytes([CMD_SYNC, CMD_SCAN]))
        self._parser.reset()
        self._last_packet_s = time.monotonic()
        self._bytes_since_packet = 0
        self.status = "streaming"

    def _wait_response(self, kind: int, size: int, timeout_s: float) -> bytes | None:
        """Payload of the first ``A5 5A`` response of type ``kind`` within the timeout, else None."""
        assert self._serial is not None
        buf = b""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            buf += self._serial.read(max(1, self._serial.in_waiting))
            start = 0
            while (i := buf.find(ANS_SYNC, start)) >= 0 and len(buf) - i >= 7:
                length = int.from_bytes(buf[i + 2:i + 6], "little") & 0x3FFFFFFF
                if buf[i + 6] == kind and length >= size:
                    if len(buf) - i - 7 >= size:
                        return buf[i + 7:i + 7 + size]
                    break
                start = i + 1
        return None

    def _read_chunk(self) -> None:
        """Read what is there (or wait up to 50 ms), feed the parser, check the no-data timeout."""
        ser = self._serial
        if ser is None:
            raise serial.SerialException("port is closed")
        data = ser.read(max(1, ser.in_waiting))
        now = time.monotonic()
        before = self._parser.packets
        if data:
            self._pending.extend(self._parser.feed(data))
        if self._parser.packets > before:
            self._last_packet_s = now
            self._bytes_since_packet = 0
            self._trouble_since = None
            if self.status != "streaming":
                self.status = "streaming"
            return
        self._bytes_since_packet += len(data)
        waited = now - self._last_packet_s
        if waited < self.no_data_timeout_s:
            return
        if self._bytes_since_packet > 0:
            self.status = f"no valid packets: check the baud rate ({self.baudrate})"
            raise DeviceError(
                f"no valid YDLiDAR packets in {waited:.1f} s on {self._path} at {self.baudrate} baud "
                f"({self._bytes_since_packet} bytes received, {self._parser.bad_checksums} bad checksums): "
                f"check the baud rate (512000 for TG30)", self.describe())
        raise _Silent(f"no bytes at all for {waited:.1f} s")

    def _disconnect(self, send_stop: bool) -> None:
        ser, self._serial = self._serial, None
        if ser is None:
            return
        if send_stop:
            try:
                ser.write(bytes([CMD_SYNC, CMD_STOP]))
                ser.flush()
            except Exception:  # noqa: BLE001 - the port may already be gone
                pass
        try:
            ser.close()
        except Exception:  # noqa: BLE001
            pass

    def _recover(self, reason: str) -> None:
        """The port failed: reopen and restart until the timeout, else raise DeviceDisconnected."""
        self._disconnect(send_stop=False)
        self._parser.reset()  # the scan in progress is incomplete; completed ones are in _pending
        if not self.reconnect:
            self.status = f"unplugged: {self._path}"
            raise DeviceDisconnected(f"{self._path} unplugged or failed ({reason}); reconnect is off",
                                     self.describe())
        self.status = f"reconnecting to {self._path} ({reason})"
        if self._trouble_since is None:
            self._trouble_since = time.monotonic()  # cleared by the next valid packet
        deadline = self._trouble_since + self.reconnect_timeout_s
        last = reason
        while time.monotonic() < deadline and not self._closed:
            try:
                self._connect()
                self.reconnects += 1
                return
            except Exception as exc:  # noqa: BLE001 - SerialException, OSError, termios.error ...
                last = str(exc)
                self._disconnect(send_stop=False)
                time.sleep(0.1)
        self.status = f"unplugged: {self._path}"
        raise DeviceDisconnected(
            f"{self._path} unplugged: not back within {self.reconnect_timeout_s:g} s ({reason}; last attempt: {last})",
            self.describe())
