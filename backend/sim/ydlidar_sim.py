"""A byte-level YDLiDAR TG30 on a pseudo-terminal, for tests and the studio's simulated rig.

:class:`YdlidarSimulator` opens a pty pair (``os.openpty``) and, in a thread, plays the device
end of the serial protocol documented in :mod:`backend.devices.ydlidar` on the master fd:
it answers ``A5 90`` (device info: model 101 = TG30, firmware 1.5), ``A5 92`` (health),
``A5 60``/``A5 61`` (start: ``A5 5A 05 00 00 40 81`` then packets) and ``A5 65``/``A5 00``
(stop), and streams a 360 degree scan at 10 Hz: one ring-start packet (one sample, CT bit 0
set, frequency code ``(10 Hz - 3) * 10``) then packets of 40 two-byte samples (distance in mm),
2000 samples a turn (20 kHz, the TG30's rate). The encoder here is written independently of
the driver's parser so that each checks the other.

The world is the shared simulated yard (:class:`backend.sim.lidar_scene.LidarScene`, the one
the ``simulated_lidar`` driver scans), seen from the scanner's pose ``T_base_scanner`` (default:
the demo rig's ground-truth ``scanner_2d`` mounting). Ranges are exact ray casts in the scan
plane at the very angles the packets encode (:meth:`YdlidarSimulator.true_ranges`), quantised
to 1 mm; a beam that hits nothing returns distance 0. Everything is deterministic.

Faults, switchable while it runs: ``garbage_every``/``garbage_len`` insert random bytes after
every n-th packet, ``corrupt_every`` spoils the check code of every n-th packet, ``wrong_baud``
replaces all output with random bytes (what a host at the wrong baud rate sees) and ignores
commands, :meth:`unplug` closes the pty (the reader's next read fails) and :meth:`replug` makes
a new one.

Reconnecting: a new pty gets a new ``/dev/pts/N``, so :attr:`port` is a symlink in a private
temporary folder that :meth:`replug` re-points, like a udev rule's ``/dev/ydlidar`` symlink
for a real USB adapter; a driver that reopens the same path finds the device again.
"""

from __future__ import annotations

import math
import struct
import time

import numpy as np

from backend.sim.demo_rig import demo_rig
from backend.sim.lidar_scene import LidarScene
from backend.sim.pty_device import PtyDevice

SCAN_RESPONSE = bytes([0xA5, 0x5A, 0x05, 0x00, 0x00, 0x40, 0x81])
TG30_MODEL = 101


def response(kind: int, payload: bytes, subtype: int = 0) -> bytes:
    """``A5 5A`` + u32 LE (size | subtype << 30) + type + payload."""
    return b"\xa5\x5a" + struct.pack("<IB", len(payload) | (subtype << 30), kind) + payload


def encode_packet(ct: int, fsa_q6: int, lsa_q6: int, distances: np.ndarray | list[int], corrupt: bool = False) -> bytes:
    """One scan packet. Angles in 1/64 degree (0..23039), distances as u16 counts (mm for TOF)."""
    samples = np.asarray(distances, dtype="<u2")
    lsn = len(samples)
    if not 1 <= lsn <= 255:
        raise ValueError(f"a packet holds 1..255 samples, not {lsn}")
    fsa = ((fsa_q6 % 23040) << 1) | 1
    lsa = ((lsa_q6 % 23040) << 1) | 1
    cs = 0x55AA ^ (ct | (lsn << 8)) ^ fsa ^ lsa
    for word in samples.tolist():
        cs ^= word
    if corrupt:
        cs ^= 0x0101
    return struct.pack("<HBBHHH", 0x55AA, ct, lsn, fsa, lsa, cs) + samples.tobytes()


class YdlidarSimulator(PtyDevice):
    """A simulated TG30 behind a pty; :attr:`port` is the path a driver opens."""

    def __init__(
        self,
        *,
        T_base_scanner: np.ndarray | None = None,
        scene: LidarScene | None = None,
        scan_hz: float = 10.0,
        samples_per_scan: int = 2000,
        samples_per_packet: int = 40,
        garbage_every: int = 0,
        garbage_len: int = 24,
        corrupt_every: int = 0,
        wrong_baud: bool = False,
        reversion: bool = True,
        inverted: bool = True,
        seed: int = 0,
    ):
        """Args:
        T_base_scanner: pose of the scanner frame (x forward, y left, z up; the scan plane is
            its x-y plane) in the scene's ``base_link`` (4x4, m); default the demo rig's
            ground-truth ``scanner_2d`` mounting.
        scene: the scene to scan; default a fresh :class:`LidarScene` (the yard with the board).
        scan_hz: revolutions per second.
        samples_per_scan, samples_per_packet: 2000 and 40 as a TG30 at 20 kHz, 10 Hz.
        garbage_every, garbage_len: random bytes after every n-th packet (0 = never).
        corrupt_every: wrong check code on every n-th packet (0 = never).
        wrong_baud: send only random bytes and ignore commands.
        reversion, inverted: how the device angle maps to the scanner frame, as the driver's
            flags (TG: theta = pi - device angle).
        seed: seeds the garbage bytes.
        """
        self.T_base_scanner = (demo_rig().T_root_frame("scanner_2d") if T_base_scanner is None
                               else np.asarray(T_base_scanner, dtype=np.float64).copy())
        self.scene = LidarScene() if scene is None else scene
        self.scan_hz = scan_hz
        self.samples_per_scan = samples_per_scan
        self.samples_per_packet = samples_per_packet
        self.garbage_every = garbage_every
        self.garbage_len = garbage_len
        self.corrupt_every = corrupt_every
        self.wrong_baud = wrong_baud
        self.reversion = reversion
        self.inverted = inverted
        self._rng = np.random.default_rng(seed)
        self.packets_sent = 0
        self.scans_started = 0
        self.corrupted_sent = 0
        self.garbage_sent = 0
        self.scanning = False
        self.commands: list[int] = []
        """Command bytes received (after ``A5``), in order."""
        super().__init__("ttyYDLIDAR")
        self._packets = self._scan_packets()

    # ------------------------------------------------------------------ geometry
    def device_to_theta(self, device_deg: np.ndarray) -> np.ndarray:
        """Device angle (deg, clockwise) to scanner-frame angle (rad, counter-clockwise from x)."""
        theta = np.radians(np.asarray(device_deg, dtype=np.float64))
        if self.reversion:
            theta = theta + math.pi
        if self.inverted:
            theta = 2 * math.pi - theta
        return (theta + math.pi) % (2 * math.pi) - math.pi

    def true_ranges(self, theta_rad: np.ndarray) -> np.ndarray:
        """Exact range (m) to the scene along scan-plane angles ``theta_rad`` (rad, scanner frame); 0 for no hit."""
        theta = np.asarray(theta_rad, dtype=np.float64).reshape(-1)
        dirs = np.column_stack([np.cos(theta), np.sin(theta), np.zeros_like(theta)])
        T = self.T_base_scanner
        t, _, _ = self.scene.cast(T[:3, 3], dirs @ T[:3, :3].T)
        return np.where(np.isfinite(t), t, 0.0)

    def _scan_packets(self) -> list[tuple[int, int, int, np.ndarray]]:
        """(ct, fsa_q6, lsa_q6, distances_mm) for one revolution; identical every turn."""
        n = self.samples_per_scan
        step_q6 = 23040.0 / n
        freq_code = int(round((self.scan_hz - 3.0) * 10)) & 0x7F  # TOF: reported = code / 10 + 3 Hz
        chunks = [(0, 1)] + [(s, min(s + self.samples_per_packet, n)) for s in range(1, n, self.samples_per_packet)]
        packets = []
        for k, (a, b) in enumerate(chunks):
            fsa = int(round(a * step_q6)) % 23040
            lsa = int(round((b - 1) * step_q6)) % 23040
            m = b - a
            span = (lsa - fsa) % 23040
            device_deg = (fsa + (span / (m - 1) if m > 1 else 0.0) * np.arange(m)) / 64.0
            mm = np.round(self.true_ranges(self.device_to_theta(device_deg)) * 1000.0)
            ct = ((freq_code << 1) | 1) if k == 0 else 0
            packets.append((ct, fsa, lsa, np.clip(mm, 0, 65535).astype(np.uint16)))
        return packets

    def scan_bytes(self, scans: int = 1) -> bytes:
        """``scans`` clean revolutions as one byte string (for parser tests and benchmarks)."""
        one = b"".join(encode_packet(*p) for p in self._packets)
        return one * scans

    # ------------------------------------------------------------------ lifecycle
    def on_plug(self) -> None:
        """Powered up (again): idle until told to scan, with no half-received command."""
        self.scanning = False
        self._cmd_buf = b""

    # ------------------------------------------------------------------ device loop
    def _handle(self, data: bytes) -> None:
        if self.wrong_baud:
            return  # the device cannot make sense of bytes at the wrong rate either
        buf = getattr(self, "_cmd_buf", b"") + data
        i = 0
        while i < len(buf) - 1:
            if buf[i] != 0xA5:
                i += 1
                continue
            cmd = buf[i + 1]
            i += 2
            self.commands.append(cmd)
            if cmd in (0x60, 0x61):
                if not self.scanning:
                    self.write(SCAN_RESPONSE)
                    self.scanning = True
                    self._t0 = time.monotonic()
                    self._sent_in_run = 0
            elif cmd in (0x65, 0x00):
                self.scanning = False
            elif cmd == 0x90 and not self.scanning:
                serial_digits = bytes([2, 0, 2, 4, 0, 1, 0, 1, 0, 0, 0, 0, 0, 0, 0, 1])
                self.write(response(0x04, struct.pack("<BHB", TG30_MODEL, 0x0105, 1) + serial_digits))
            elif cmd == 0x92 and not self.scanning:
                self.write(response(0x06, bytes([0, 0, 0])))
        self._cmd_buf = buf[i:]

    def serve(self) -> None:
        period = 1.0 / (self.scan_hz * len(self._packets))
        self._cmd_buf = b""
        last_noise = time.monotonic()
        while not self.stopping:
            data = self.read(0.005)
            if data is None:
                return
            if data:
                self._handle(data)
            now = time.monotonic()
            if self.wrong_baud:
                n = int((now - last_noise) * 45000)  # about the TG30's byte rate
                if n > 0:
                    last_noise = now
                    if not self.write(self._rng.integers(0, 256, n, dtype=np.uint8).tobytes()):
                        return
                continue
            last_noise = now
            if not self.scanning:
                continue
            due = int((now - self._t0) / period) + 1
            if due - self._sent_in_run > 3 * len(self._packets):
                # the reader fell far behind (the pty is full): drop whole turns, as a UART overrun would
                behind = due - self._sent_in_run
                self._sent_in_run += (behind // len(self._packets)) * len(self._packets)
            out = []
            while self._sent_in_run < due:
                k = self._sent_in_run % len(self._packets)
                if k == 0:
                    self.scans_started += 1
                self.packets_sent += 1
                self._sent_in_run += 1
                corrupt = self.corrupt_every > 0 and self.packets_sent % self.corrupt_every == 0
                self.corrupted_sent += corrupt
                out.append(encode_packet(*self._packets[k], corrupt=corrupt))
                if self.garbage_every > 0 and self.packets_sent % self.garbage_every == 0:
                    out.append(self._rng.integers(0, 256, self.garbage_len, dtype=np.uint8).tobytes())
                    self.garbage_sent += self.garbage_len
            if out and not self.write(b"".join(out)):
                return
