"""A byte-level Hokuyo UTM-30LX-EW on TCP, for tests and the studio's simulated rigs.

:class:`HokuyoSimulator` listens on ``127.0.0.1`` and, in a thread, plays the device end of SCIP 2.0 as
documented in Hokuyo's "Communication Protocol Specification For SCIP2.0 Standard" and the UTM-30LX-EW's
specification, to one client at a time: a reply is the echo of the command line, a status line, data lines
and an empty line; a line's check char is ``(sum of its data bytes & 0x3F) + 0x30``; values are 6-bit
chars (+0x30), 3 for a distance (mm) or an intensity, 4 for a timestamp (ms since :meth:`start`, modulo
2^24). Commands: ``VV``, ``PP``, ``II`` (information), ``BM`` (laser on), ``QT`` (stop, laser off),
``RS`` (reset), ``TM0``/``TM1``/``TM2`` (time-sync mode), ``MD``/``ME`` (stream distances, or distances
and intensities: ``ssssEEEEggSnn``) and ``GD``/``GE`` (one scan: ``ssssEEEEgg``), grouping 00/01 only;
anything else gets ``0E``. A turn takes 25 ms (2400 rpm); each scan is sent, stamped, when its turn ends,
paced by the clock; a scan the reader has no room for is dropped (:attr:`scans_dropped`), not queued.
The encoder is written independently of :mod:`backend.devices.hokuyo` so that each checks the other.

The world is the shared yard (:class:`backend.sim.lidar_scene.LidarScene`) seen from ``T_base_scanner``
(default the demo rig's ground-truth ``scanner_2d`` mounting) or from what a callable ``pose`` returns
when each scan is made (a scanner on a moving servo horn). Step ``i`` looks along ``(i - 540) * 2 pi /
1440`` rad in the scanner's x-y plane, counter-clockwise from x (steps 0..1080: -135..+135 deg). Ranges
are exact ray casts rounded to 1 mm (optional seeded noise ``range_noise_m``); a miss, or a return outside
23 mm..60 m, reads the error value 1 with intensity 0. Intensity is the surface's reflectivity (as in
:meth:`LidarScene.scan_2d`, board ink included) times an incidence term, about 0..10000.
:meth:`HokuyoSimulator.true_scan` is exactly what is encoded; :attr:`HokuyoSimulator.scan_poses` keeps
each sent scan's timestamp and pose.

Faults, switchable while it runs: ``corrupt_every`` spoils one data line's check char in every n-th scan
streamed to a connection; ``drop_after_scans`` closes a connection once it was streamed that many scans
(the server keeps listening); ``laser_fault``: the laser does not light (``BM``, ``MD``/``ME`` answer
``01``, ``GD``/``GE`` ``10``, a stream stops); ``refuse_connections`` closes each new connection at once.
A client's disconnect resets the device (streaming stopped, laser off, time-sync mode left).

The USB-serial models speak the same SCIP 2.0 over a CDC-ACM port: :class:`HokuyoUsbSimulator` plays the same
device (:meth:`HokuyoSimulator.exchange`, no socket) on a pty behind a stable path, as ``/dev/ttyACM0`` would be.

Usage: ``with HokuyoSimulator() as sim: sock = socket.create_connection((sim.host, sim.port))``, or
``with HokuyoUsbSimulator() as usb: serial.Serial(usb.port)``.
"""

from __future__ import annotations

import collections
import math
import select
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Self

import numpy as np

from backend.core.transforms import invert, transform_points
from backend.sim.demo_rig import demo_rig
from backend.sim.lidar_scene import BOARD_INK_INTENSITY, LABELS, LidarScene, label_reflectivity
from backend.sim.pty_device import PtyDevice

N_STEPS = 1081
"""Steps 0..1080 (AMIN..AMAX), 1440 steps a turn (ARES), step 540 straight ahead (AFRT)."""
SCAN_PERIOD_S = 0.025
"""One turn at 2400 rpm (s)."""
DMIN_MM, DMAX_MM = 23, 60000
ERROR_VALUE = 1
"""Distance sent for a miss or a return outside DMIN..DMAX (mm; below DMIN, so a driver drops it)."""
INTENSITY_SCALE = 40.0
"""Intensity per unit of :data:`~backend.sim.lidar_scene.REFLECTIVITY` (230 x 40 = 9200 for the white board)."""
LINE_CHARS = 64

VERSION = [("VEND", "Hokuyo Automatic Co.,Ltd."), ("PROD", "SOKUIKI Sensor TOP-URG UTM-30LX-EW"),
           ("FIRM", "1.1.02(23/Aug./2012)"), ("PROT", "SCIP 2.0"), ("SERI", "H1630567")]
PARAMETERS = [("MODL", "UTM-30LX-EW"), ("DMIN", "23"), ("DMAX", "60000"), ("ARES", "1440"), ("AMIN", "0"),
              ("AMAX", "1080"), ("AFRT", "540"), ("SCAN", "2400")]


def checksum(data: bytes) -> bytes:
    """The SCIP 2.0 check char of a line's data."""
    return bytes([(sum(data) & 0x3F) + 0x30])


def encode(values: np.ndarray | list[int] | int, n_chars: int) -> bytes:
    """Non-negative integers as ``n_chars`` 6-bit chars each (most significant first), concatenated."""
    v = np.asarray(values, dtype=np.int64).reshape(-1, 1)
    shifts = 6 * np.arange(n_chars - 1, -1, -1)
    return (((v >> shifts) & 0x3F) + 0x30).astype(np.uint8).tobytes()


def status_line(code: bytes) -> bytes:
    """Two status chars + check char + LF."""
    return code + checksum(code) + b"\n"


def data_lines(payload: bytes, corrupt: bool = False) -> bytes:
    """``payload`` cut into lines of 64 chars, each + check char + LF; ``corrupt`` spoils the first line's check."""
    out = []
    for k in range(0, len(payload), LINE_CHARS):
        line = payload[k:k + LINE_CHARS]
        check = checksum(line)
        if corrupt and k == 0:
            check = bytes([((check[0] - 0x30 + 1) & 0x3F) + 0x30])
        out.append(line + check + b"\n")
    return b"".join(out)


def info_lines(pairs: list[tuple[str, str]]) -> bytes:
    """``KEY:value;`` + check char of ``KEY:value`` + LF for each pair."""
    lines = [f"{k}:{v}".encode("latin-1") for k, v in pairs]
    return b"".join(line + b";" + checksum(line) + b"\n" for line in lines)


@dataclass
class _Job:
    """A scan request under way: a stream (MD/ME) or one scan (GD/GE)."""

    echo: bytes
    intensity: bool
    start: int
    end: int
    stream: bool
    every: int = 1
    """Send every n-th turn (skip count + 1)."""
    remaining: int | None = None
    """Scans still to send; None = until QT."""
    next_due: float = 0.0
    """``time.monotonic()`` at which the next scan to send ends (s)."""


class HokuyoSimulator:
    """A simulated UTM-30LX-EW serving SCIP 2.0 on ``host:port``; :meth:`start` it, :meth:`stop` it."""

    def __init__(self, *, port: int = 0, host: str = "127.0.0.1", T_base_scanner: np.ndarray | None = None,
                 pose: Callable[[], np.ndarray] | None = None, scene: LidarScene | None = None,
                 range_noise_m: float = 0.0, seed: int = 0, corrupt_every: int = 0, drop_after_scans: int = 0,
                 laser_fault: bool = False, refuse_connections: bool = False, max_poses: int = 10000):
        """Args:
        port: TCP port to listen on (0 = a free one, see :attr:`port` after :meth:`start`). host: address.
        T_base_scanner: pose of the scanner frame (x forward, y left, z up; scan plane x-y) in the scene's
            ``base_link`` (4x4, m); default the demo rig's ground-truth ``scanner_2d`` mounting.
        pose: if given, called when each scan is made for the current ``T_base_scanner`` (overrides it).
        scene: the scene to scan; default a fresh :class:`LidarScene` (the yard with the board).
        range_noise_m: 1-sigma Gaussian range noise (m), seeded by ``(seed, timestamp_ms)``; 0 = exact.
        corrupt_every, drop_after_scans, laser_fault, refuse_connections: the faults (0/False = off).
        max_poses: how many entries :attr:`scan_poses` keeps.
        """
        self.host, self.port = host, int(port)
        self.T_base_scanner = (demo_rig().T_root_frame("scanner_2d") if T_base_scanner is None
                               else np.asarray(T_base_scanner, dtype=np.float64).copy())
        self.pose = pose
        self.scene = LidarScene() if scene is None else scene
        self.range_noise_m = float(range_noise_m)
        self.seed = int(seed)
        self.corrupt_every = int(corrupt_every)
        self.drop_after_scans = int(drop_after_scans)
        self.laser_fault = bool(laser_fault)
        self.refuse_connections = bool(refuse_connections)
        self.commands: list[str] = []
        """Command lines received (without terminator), in order."""
        self.scans_sent = 0
        """Scan messages sent (streamed and GD/GE)."""
        self.scans_dropped = 0
        """Streamed scans not sent because the reader was behind."""
        self.corrupted_sent = 0
        self.connections_dropped = 0
        self.connections_refused = 0
        self.scan_poses: collections.deque[tuple[int, np.ndarray]] = collections.deque(maxlen=max_poses)
        """(timestamp_ms, T_base_scanner) of each scan sent, oldest first."""
        theta = (np.arange(N_STEPS) - 540) * 2 * math.pi / 1440
        self._dirs = np.column_stack([np.cos(theta), np.sin(theta), np.zeros(N_STEPS)])
        self._t0 = time.monotonic()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._listener: socket.socket | None = None
        self._client: socket.socket | None = None
        self._inbuf, self._out = b"", bytearray()
        self._conn_scans, self._closing = 0, None
        self._reset()

    # ------------------------------------------------------------------ truth
    def true_scan(self, T_base_scanner: np.ndarray, timestamp_ms: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(distance (1081,) int mm, intensity (1081,) int)`` of steps 0..1080 from ``T_base_scanner`` (4x4, m).

        Exactly what is encoded; with ``range_noise_m`` the noise of the scan stamped ``timestamp_ms``
        is added (none if it is None). Misses and returns outside 23 mm..60 m read 1 with intensity 0.
        """
        T = np.asarray(T_base_scanner, dtype=np.float64)
        dirs = self._dirs @ T[:3, :3].T
        t, labels, normals = self.scene.cast(T[:3, 3], dirs)
        hit = np.isfinite(t)
        r = np.where(hit, t, 0.0)
        if self.range_noise_m > 0 and timestamp_ms is not None:
            r = r + np.random.default_rng([self.seed, int(timestamp_ms)]).normal(0.0, self.range_noise_m, N_STEPS)
        mm = np.round(r * 1000.0)
        valid = hit & (mm >= DMIN_MM) & (mm <= DMAX_MM)
        reflect = label_reflectivity(labels).astype(np.float64)
        on_board = np.flatnonzero(labels == LABELS["board"])
        if on_board.size:
            hits_base = T[:3, 3] + dirs[on_board] * t[on_board, None]
            hits_board = transform_points(invert(self.scene.T_base_board), hits_base)
            reflect[on_board[self.scene.on_black_square(hits_board)]] = BOARD_INK_INTENSITY
        cos_incidence = np.abs(np.einsum("ij,ij->i", np.nan_to_num(normals), dirs))
        intensity = np.round(reflect * (0.35 + 0.65 * cos_incidence) * INTENSITY_SCALE)
        return (np.where(valid, mm, ERROR_VALUE).astype(np.int64), np.where(valid, intensity, 0).astype(np.int64))

    def timestamp_ms(self, at: float | None = None) -> int:
        """The sensor's clock (ms since :meth:`start`, modulo 2^24) at ``time.monotonic()`` ``at`` (default now)."""
        return round(((time.monotonic() if at is None else at) - self._t0) * 1000.0) % (1 << 24)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> Self:
        """Listen and serve. Safe twice."""
        if self._thread is not None:
            return self
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind((self.host, self.port))
        self._listener.listen(4)
        self.port = self._listener.getsockname()[1]
        self._t0 = time.monotonic()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"sim-hokuyo-{self.port}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Close every connection and the listener, join the thread. Safe twice."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self._disconnect()
        if self._listener is not None:
            self._listener.close()
            self._listener = None

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def exchange(self, received: bytes) -> bytes:
        """The device without its socket: take ``received`` (what the driver sent since the last call, maybe
        nothing), send the scans whose turn has ended, and return every byte now due to the driver. For a
        transport of its own (:class:`HokuyoUsbSimulator`'s pty); the TCP server loop does the same itself."""
        if received:
            self._receive(received)
        self._tick()
        out, self._out = bytes(self._out), bytearray()
        return out

    # ------------------------------------------------------------------ server loop
    def _reset(self) -> None:
        """What a power cycle (or a client's disconnect) resets."""
        self.laser_on = self.time_sync = False
        self._stream: _Job | None = None
        self._get: _Job | None = None

    def _disconnect(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
        self._reset()

    def _run(self) -> None:
        self._reset()
        while not self._stop.is_set():
            if self._client is None:
                self._accept()
                continue
            jobs = [j for j in (self._stream, self._get) if j is not None]
            wait = min([0.02] + [max(0.0, j.next_due - time.monotonic()) for j in jobs])
            try:
                readable, _, _ = select.select([self._client], [self._client] if self._out else [], [], wait)
                if readable:
                    data = self._client.recv(4096)
                    if not data:
                        self._disconnect()
                        continue
                    self._receive(data)
                if self._out:
                    del self._out[:self._client.send(self._out)]
            except BlockingIOError:
                pass
            except OSError:
                self._disconnect()
                continue
            if self._closing is not None and (not self._out or time.monotonic() > self._closing):
                self.connections_dropped += 1
                self._disconnect()
                continue
            self._tick()

    def _accept(self) -> None:
        assert self._listener is not None
        if not select.select([self._listener], [], [], 0.02)[0]:
            return
        conn, _ = self._listener.accept()
        if self.refuse_connections:
            conn.close()
            self.connections_refused += 1
            return
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 16384)  # a small queue: a slow reader loses scans
        conn.setblocking(False)
        self._client, self._inbuf, self._out = conn, b"", bytearray()
        self._conn_scans, self._closing = 0, None
        self._reset()

    def _receive(self, data: bytes) -> None:
        self._inbuf += data
        *lines, self._inbuf = self._inbuf.split(b"\n")
        self._inbuf = self._inbuf[-1024:]
        for line in lines:
            line = line[:-1] if line.endswith(b"\r") else line
            if line:
                self.commands.append(line.decode("latin-1"))
                self._out += self._answer(line)

    def _answer(self, echo: bytes) -> bytes:
        """The immediate reply to one command line (empty while a GD/GE waits for its scan)."""
        body = echo.split(b";", 1)[0]
        name, params = (body[:3], body[3:]) if body.startswith(b"%") else (body[:2], body[2:])
        head = echo + b"\n"
        if name in (b"VV", b"PP", b"II", b"BM", b"QT", b"RS") and params:
            return head + status_line(b"0C") + b"\n"
        if name in (b"VV", b"PP", b"II"):
            pairs = VERSION if name == b"VV" else PARAMETERS if name == b"PP" else [
                ("MODL", "UTM-30LX-EW"), ("LASR", "ON" if self.laser_on else "OFF"), ("SCSP", "2400"),
                ("MESM", "Measuring by Sensitive Mode"), ("SBPS", "Ethernet 100 [Mbps]"),
                ("TIME", encode(self.timestamp_ms(), 4).decode("latin-1")), ("STAT", "Sensor works well.")]
            return head + status_line(b"00") + info_lines(pairs) + b"\n"
        if name == b"BM":
            code = b"01" if self.laser_fault else b"02" if self.laser_on else b"00"
            self.laser_on = self.laser_on or not self.laser_fault
            return head + status_line(code) + b"\n"
        if name in (b"QT", b"RS"):
            self.laser_on, self._stream, self._get = False, None, None
            self.time_sync = self.time_sync and name == b"QT"
            return head + status_line(b"00") + b"\n"
        if name == b"TM":
            if params == b"1":
                if not self.time_sync:
                    return head + status_line(b"04") + b"\n"
                stamp = encode(self.timestamp_ms(), 4)
                return head + status_line(b"00") + stamp + checksum(stamp) + b"\n\n"
            codes = {b"0": b"02" if self.time_sync else b"00", b"2": b"00" if self.time_sync else b"03"}
            self.time_sync = {b"0": True, b"2": False}.get(params, self.time_sync)
            return head + status_line(codes.get(params, b"01")) + b"\n"
        if name in (b"MD", b"ME", b"GD", b"GE"):
            stream = name[0:1] == b"M"
            if len(params) != (13 if stream else 10) or not params.isdigit():
                return head + status_line(b"0C") + b"\n"
            start, end, group = int(params[0:4]), int(params[4:8]), int(params[8:10])
            if end >= N_STEPS or start > end:
                return head + status_line(b"0D") + b"\n"
            if group > 1:
                return head + status_line(b"0F") + b"\n"
            job = _Job(echo, name[1:2] == b"E", start, end, stream)
            turns = math.floor((time.monotonic() - self._t0) / SCAN_PERIOD_S)
            job.next_due = self._t0 + (turns + 2) * SCAN_PERIOD_S  # the end of the first whole turn from now
            if not stream:
                if not self.laser_on or self.laser_fault:
                    return head + status_line(b"10") + b"\n"
                self._get = job
                return b""
            if self.laser_fault:
                return head + status_line(b"01") + b"\n"
            job.every, n = int(params[10:11]) + 1, int(params[11:13])
            job.remaining = n if n > 0 else None
            self.laser_on, self._stream = True, job
            return head + status_line(b"00") + b"\n"
        return head + status_line(b"0E") + b"\n"

    def _tick(self) -> None:
        """Send the scans whose turn has ended."""
        now, behind = time.monotonic(), bool(self._out)
        if self._stream is not None and self.laser_fault:
            self._stream = None
        for job in [j for j in (self._get, self._stream) if j is not None and now >= j.next_due]:
            period = SCAN_PERIOD_S * job.every
            missed = int((now - job.next_due) / period)  # turns that ended while the thread was busy
            due, job.next_due = job.next_due + missed * period, job.next_due + (missed + 1) * period
            if job.stream:
                self.scans_dropped += missed + behind
                if behind:  # the reader is behind (the socket's small queue is full): this scan is lost
                    continue
            else:
                self._get = None
                self._out += self._scan_message(job, job.echo, b"00", due)
                continue
            if job.remaining is not None:
                job.remaining -= 1
            echo = job.echo[:13] + b"%02d" % (job.remaining or 0) + job.echo[15:]
            self._conn_scans += 1
            corrupt = self.corrupt_every > 0 and self._conn_scans % self.corrupt_every == 0
            self.corrupted_sent += corrupt
            self._out += self._scan_message(job, echo, b"99", due, corrupt)
            if job.remaining == 0:
                self._stream = None
            if self.drop_after_scans > 0 and self._conn_scans >= self.drop_after_scans and self._closing is None:
                self._closing = now + 1.0  # once the scan is out (or after 1 s), close
                self._stream = self._get = None

    def _scan_message(self, job: _Job, echo: bytes, status: bytes, due: float, corrupt: bool = False) -> bytes:
        """One scan's message, ray-cast now from the current pose and stamped with the end of its turn ``due``."""
        T = np.asarray(self.pose() if self.pose is not None else self.T_base_scanner, dtype=np.float64).copy()
        stamp = self.timestamp_ms(due)
        ranges, intensity = self.true_scan(T, stamp)
        sl = slice(job.start, job.end + 1)
        if job.intensity:
            payload = encode(np.column_stack([ranges[sl], intensity[sl]]), 3)
        else:
            payload = encode(ranges[sl], 3)
        self.scan_poses.append((stamp, T))
        self.scans_sent += 1
        ts = encode(stamp, 4)
        return echo + b"\n" + status_line(status) + ts + checksum(ts) + b"\n" + data_lines(payload, corrupt) + b"\n"


class HokuyoUsbSimulator(PtyDevice):
    """A USB-serial Hokuyo (SCIP 2.0 over CDC-ACM) on a pty: :class:`HokuyoSimulator`'s device, with the same
    settings (its TCP faults aside), answering at :attr:`port`."""

    def __init__(self, **settings: Any):
        super().__init__("ttyACM-hokuyo")
        self.sensor = HokuyoSimulator(**settings)
        """The simulated device (never listening on TCP): its truth, commands and counters."""

    def on_plug(self) -> None:
        self.sensor._reset()

    def serve(self) -> None:
        while not self.stopping:
            received = self.read(0.005)
            if received is None:
                return
            out = self.sensor.exchange(received)
            if out and not self.write(out):
                return
