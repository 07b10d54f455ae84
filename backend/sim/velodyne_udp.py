"""A live simulated VLP-16 on the network: data packets of the shared yard, sent over UDP in real time.

:class:`Vlp16UdpSimulator` sends, from a daemon thread, the data packets of a VLP-16 spinning in
the shared simulated yard (:func:`~backend.sim.velodyne_packets.scene_ranges_fn`, the
:class:`~backend.sim.lidar_scene.LidarScene` the other simulated LiDARs scan) to ``host:port``
at the sensor's packet rate (one packet per 1327.104 us, ~753.5 packets/s), so
:class:`backend.devices.velodyne.VelodyneUdp` reads it like a sensor on the wire.

The scene is static, so one turn of packets is computed when the simulator is made and then sent
over and over, restamped with the sensor's clock (microseconds past the hour, started from the
host's wall clock). The turn is rounded to a whole number of packets so that turns join without a
seam: at the default 600 rpm a turn is 75 packets, i.e. the simulated sensor spins at 602.8 rpm
(10.05 scans/s; a real VLP-16 is not exactly on its set speed either). A burst of the packets due
by the clock goes out every ``burst_s``, so the thread sleeps between bursts instead of spinning.

Faults, switchable while it runs: ``garbage_every`` sends three malformed datagrams (text, a
packet cut short, a packet-sized block of zeros) before every n-th packet; :meth:`unplug` stops
sending (a pulled cable) and :meth:`replug` resumes, at the azimuth the still-spinning sensor has
reached by then.
"""

from __future__ import annotations

import socket
import threading
import time
from typing import Self

import numpy as np

from backend.sim.velodyne_packets import (
    PACKET_PERIOD_US,
    PACKET_SIZE,
    TIMESTAMP_OFFSET,
    Vlp16Sim,
    scene_ranges_fn,
    simulate_vlp16_scan,
)

_HOUR_US = 3_600_000_000


class Vlp16UdpSimulator:
    """A simulated VLP-16 sending its data packets to ``host:port`` over UDP; :meth:`start` it, :meth:`stop` it."""

    def __init__(self, port: int, *, host: str = "127.0.0.1", T_base_lidar: np.ndarray | None = None,
                 rpm: float = 600.0, garbage_every: int = 0, burst_s: float = 0.01):
        """Compute the turn of packets (ray-casting the yard once).

        Args:
            port: UDP port to send to (the driver's bound port; 2368 for a real sensor's host).
            host: address to send to.
            T_base_lidar: pose of the sensor frame (x forward, y left, z up) in the yard's
                ``base_link`` (4x4, m); default the demo rig's ground-truth ``lidar_top`` mounting.
            rpm: rotation speed, rounded so that a turn is a whole number of packets (see :attr:`rpm`).
            garbage_every: before every n-th packet send three malformed datagrams (0 = never).
            burst_s: time between two bursts of packets (s).
        """
        if rpm <= 0:
            raise ValueError(f"rpm must be positive, not {rpm}")
        self.address = (host, int(port))
        packets_per_turn = max(1, round(60e6 / rpm / PACKET_PERIOD_US))
        self.rpm = 60e6 / (packets_per_turn * PACKET_PERIOD_US)
        """Rotation speed actually simulated (rev/min): a whole number of packets per turn."""
        self.turn: Vlp16Sim = simulate_vlp16_scan(scene_ranges_fn(T_base_lidar=T_base_lidar), rpm=self.rpm)
        """The one turn of packets sent over and over, with its ground truth (sensor frame, m)."""
        self.garbage_every = int(garbage_every)
        self.burst_s = float(burst_s)
        self.packets_sent = 0
        """Data packets sent so far (not counting garbage)."""
        self._packets = np.frombuffer(b"".join(self.turn.packets), np.uint8).reshape(-1, PACKET_SIZE)
        self._plugged = threading.Event()
        self._plugged.set()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sock: socket.socket | None = None

    @property
    def plugged(self) -> bool:
        """False between :meth:`unplug` and :meth:`replug`."""
        return self._plugged.is_set()

    def start(self) -> Self:
        """Start spinning and sending (the sensor's first packet is at azimuth 0). Safe twice."""
        if self._thread is not None:
            return self
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.connect(self.address)
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"sim-vlp16-udp-{self.address[1]}", daemon=True)
        self._thread.start()
        return self

    def unplug(self) -> None:
        """Pull the cable: nothing is sent until :meth:`replug`; the sensor keeps spinning."""
        self._plugged.clear()

    def replug(self) -> None:
        """Plug the cable back in: packets flow again, from the azimuth the sensor is at now."""
        self._plugged.set()

    def stop(self) -> None:
        """Stop sending and release the socket. Safe twice."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        sock = self._sock
        assert sock is not None
        period_s = PACKET_PERIOD_US * 1e-6
        clock_us = int(time.time() % 3600 * 1e6)  # the sensor's clock: us past the hour
        t0 = time.monotonic()
        next_packet = 0  # index (since start) of the next packet the sensor fires
        while not self._stop.is_set():
            due = int((time.monotonic() - t0) / period_s) + 1
            if self._plugged.is_set() and due > next_packet:
                self._send(sock, np.arange(next_packet, due), clock_us)
            next_packet = due  # unplugged, the packets fired meanwhile go nowhere
            self._stop.wait(self.burst_s)

    def _send(self, sock: socket.socket, indices: np.ndarray, clock_us: int) -> None:
        """Send packets ``indices`` (counted from the start) of the endless stream, restamped."""
        burst = self._packets[indices % len(self._packets)]  # a copy
        stamps = (clock_us + np.round(indices * PACKET_PERIOD_US).astype(np.int64)) % _HOUR_US
        burst[:, TIMESTAMP_OFFSET:TIMESTAMP_OFFSET + 4] = stamps.astype("<u4").view(np.uint8).reshape(-1, 4)
        for index, packet in zip(indices.tolist(), burst, strict=True):
            try:
                if self.garbage_every and index % self.garbage_every == 0:
                    sock.send(b"\xff\xee not a packet")
                    sock.send(packet[:600])
                    sock.send(bytes(PACKET_SIZE))
                sock.send(packet)
            except ConnectionRefusedError:
                pass  # nobody listens on the port (yet): a sensor sends regardless
            self.packets_sent += 1
