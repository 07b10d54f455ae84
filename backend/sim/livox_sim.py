"""A simulated Livox SDK 1 LiDAR (Avia or Horizon) on 127.0.0.1: control frames, point and IMU packets, byte for byte.

:class:`LivoxSimulator` runs one daemon thread around a UDP command socket (the LiDAR's port 65000; a free port
here) and behaves as the Livox SDK communication protocol describes a LiDAR
(:mod:`backend.devices.livox_packets` has the wire format):

- while no host is connected it broadcasts its broadcast code and device type from its command socket to
  ``127.0.0.1:discovery_port`` once a second (a real LiDAR sends to 255.255.255.255:55000);
- it answers a handshake (host IP, data, command and IMU ports) with return code 0, and then heartbeats, start and
  stop sampling, the return mode (first, strongest, dual), the IMU push frequency (off, 200 Hz) and disconnect,
  each acknowledged with correct CRCs; requests from a host other than the connected one are refused (return code 1);
- it drops the host after ``heartbeat_timeout_s`` (3 s, as the firmware) without a heartbeat, stops sampling and
  broadcasts again;
- while sampling it sends, in real time, data packets of type 2 (96 single returns) or, in dual-return mode, type 4
  (48 firings of two returns), time stamped in ns (time stamp type 0, no sync) from ``clock0_ns``, and with the IMU
  on, type 6 packets at 200 Hz.

**Returns.** Firing ``k`` (at ``clock0_ns + k * 4167`` ns) points along :mod:`backend.sim.livox_pattern`'s
non-repetitive pattern of the model; it is ray-cast in the shared yard (:class:`~backend.sim.lidar_scene.LidarScene`)
from ``T_base_lidar`` (default the demo rig's ``lidar_front`` mounting), with Gaussian range noise ``range_noise_m``
(1-sigma; the Avia's and Horizon's data sheets give 2 cm) and quantised to the packets' whole millimetres. A ray
that hits nothing within 450 m is sent as (0, 0, 0), Livox's "no return". In dual-return mode the second return is
the next surface facing the ray behind the solid it hit first (as if part of the beam passed it: a pole, a box's
edge in front of a wall), or none (nothing behind it: the floor, the walls).
Reflectivity is the surface's :data:`~backend.sim.lidar_scene.REFLECTIVITY` scaled by the incidence
(``0.35 + 0.65 cos``). :meth:`LivoxSimulator.truth` ray-casts the noise-free returns of any firings, for tests.

**IMU.** The sensor is static: the gyro reads ``gyro_bias_rad_s`` and the accelerometer the specific force of
gravity (+1 g up) in the LiDAR's axes, in g as Livox sends it, each with Gaussian noise (``gyro_noise_rad_s``,
``accel_noise_g``).

Faults, switchable while it runs: :meth:`unplug` makes it deaf and mute (a pulled cable; it keeps its clock and,
after ``heartbeat_timeout_s``, drops the host) and :meth:`replug` undoes it; ``drop_heartbeat_acks`` keeps it
streaming but stops the heartbeat acknowledgements; ``protocol_version`` is the version byte of its data packets
(5 for SDK 1).
"""

from __future__ import annotations

import select
import socket
import threading
import time
from typing import Self

import numpy as np

from backend.devices.livox import (
    CMD_IMU_PUSH,
    CMD_RETURN_MODE,
    CMD_SET_LIDAR,
    IMU_PERIOD_NS,
    MODEL_TYPES,
    RETURN_MODES,
)
from backend.devices.livox_packets import (
    BROADCAST,
    CMD_BROADCAST,
    CMD_DISCONNECT,
    CMD_HANDSHAKE,
    CMD_HEARTBEAT,
    CMD_SAMPLING,
    CMD_SET_GENERAL,
    CMD_TYPE_ACK,
    CMD_TYPE_MESSAGE,
    CMD_TYPE_REQUEST,
    DATA_TYPE_DUAL_EXTEND_CARTESIAN,
    DATA_TYPE_EXTEND_CARTESIAN,
    DATA_TYPE_IMU,
    DATA_TYPES,
    DUAL_EXTEND_CARTESIAN,
    ETH_HEADER,
    EXTEND_CARTESIAN,
    HANDSHAKE,
    HEARTBEAT_ACK,
    IMU_POINT,
    SDK1_PROTOCOL_VERSION,
    STANDARD_GRAVITY_M_S2,
    Frame,
    pack_frame,
    parse_frame,
)
from backend.sim.demo_rig import demo_rig
from backend.sim.lidar_scene import LidarScene, label_reflectivity
from backend.sim.livox_pattern import PATTERNS, ScanPattern

MAX_RANGE_M = 450.0
"""Longest return (m; the Avia's data sheet, at 80 % reflectivity)."""
SECOND_RETURN_GAP_M = 0.01
"""How far behind the first surface the ray is cast again for the second return (m)."""
_MAX_BURST_S = 0.5
"""Firings further behind than this are skipped, not sent late (a stalled thread)."""


class LivoxSimulator:
    """A simulated Livox SDK 1 LiDAR on 127.0.0.1 (see the module docstring); :meth:`start` it, :meth:`stop` it."""

    def __init__(self, discovery_port: int, *, model: str = "Avia", T_base_lidar: np.ndarray | None = None,
                 scene: LidarScene | None = None, range_noise_m: float = 0.02, broadcast_code: str = "1PQDH5B00100041",
                 heartbeat_timeout_s: float = 3.0, gyro_bias_rad_s: tuple[float, float, float] = (0.002, -0.001, 0.003),
                 gyro_noise_rad_s: float = 0.001, accel_noise_g: float = 0.002, seed: int = 0,
                 clock0_ns: int = 7_000_000_000, burst_s: float = 0.01, host: str = "127.0.0.1"):
        """Build the simulated LiDAR (not started).

        Args:
            discovery_port: UDP port on ``host`` its broadcasts go to (the driver's discovery port).
            model: ``"Avia"`` or ``"Horizon"`` (:data:`~backend.sim.livox_pattern.PATTERNS`).
            T_base_lidar: pose of the LiDAR frame in the yard's ``base_link`` (4x4, m); default the demo rig's
                ``lidar_front``.
            scene: the scene to scan; default a fresh :class:`LidarScene`.
            range_noise_m: 1-sigma Gaussian range noise (m).
            broadcast_code: its 15-character broadcast code.
            heartbeat_timeout_s: how long it keeps a host without heartbeats (s).
            gyro_bias_rad_s: what its gyro reads at rest (rad/s, LiDAR axes).
            gyro_noise_rad_s, accel_noise_g: 1-sigma IMU noise (rad/s, g).
            seed: seed of the noise.
            clock0_ns: its clock (ns since power-on) at :meth:`start`.
            burst_s: time between two bursts of packets (s).
            host: the address it lives on and sends to.
        """
        if model not in PATTERNS:
            raise ValueError(f"no simulated Livox {model!r}; simulated models: {', '.join(PATTERNS)}")
        if not (range_noise_m >= 0 and heartbeat_timeout_s > 0 and burst_s > 0):
            raise ValueError("range_noise_m must be >= 0, heartbeat_timeout_s and burst_s > 0")
        self.model = model
        self.pattern: ScanPattern = PATTERNS[model]
        self.device_type = MODEL_TYPES[model]
        self.T_base_lidar = (demo_rig().T_root_frame("lidar_front") if T_base_lidar is None
                             else np.asarray(T_base_lidar, float).copy())
        self.scene = LidarScene() if scene is None else scene
        self.range_noise_m = float(range_noise_m)
        self.broadcast_code = broadcast_code
        self.heartbeat_timeout_s = float(heartbeat_timeout_s)
        self.gyro_bias_rad_s = np.asarray(gyro_bias_rad_s, float)
        self.gyro_noise_rad_s, self.accel_noise_g = float(gyro_noise_rad_s), float(accel_noise_g)
        self.clock0_ns = int(clock0_ns)
        """Its clock at :meth:`start` (ns): firing ``k`` is stamped ``clock0_ns + k * point_interval_ns``."""
        self.burst_s = float(burst_s)
        self.host = host
        self.discovery_address = (host, int(discovery_port))
        self.drop_heartbeat_acks = False
        """True: heartbeats are received (the host stays connected) but not acknowledged."""
        self.protocol_version = SDK1_PROTOCOL_VERSION
        """The version byte of its data packets."""
        self.return_mode = RETURN_MODES["first"]
        self.imu_on = False
        self.host_address: tuple[str, int] | None = None
        """The connected host's command address, None while broadcasting."""
        self.sampling = False
        self.packets_sent = 0
        """Point data packets sent so far."""
        self.imu_packets_sent = 0
        self.heartbeats = 0
        """Heartbeats received so far."""
        self._data_address: tuple[str, int] | None = None
        self._imu_address: tuple[str, int] | None = None
        self._rng = np.random.default_rng(seed)
        self._plugged = threading.Event()
        self._plugged.set()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sock: socket.socket | None = None
        self._out: socket.socket | None = None
        self._last_heartbeat = 0.0

    # ---------------------------------------------------------------------------------------- control

    @property
    def command_port(self) -> int:
        """Its command port (bound by :meth:`start`)."""
        return self._sock.getsockname()[1] if self._sock is not None else 0

    @property
    def connected(self) -> bool:
        return self.host_address is not None

    @property
    def plugged(self) -> bool:
        return self._plugged.is_set()

    def start(self) -> Self:
        """Bind its command socket on ``host`` and start broadcasting. Safe twice."""
        if self._thread is not None:
            return self
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind((self.host, 0))
        self._out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"sim-livox-{self.command_port}", daemon=True)
        self._thread.start()
        return self

    def unplug(self) -> None:
        """Pull the cable: nothing in, nothing out, until :meth:`replug`."""
        self._plugged.clear()

    def replug(self) -> None:
        self._plugged.set()

    def stop(self) -> None:
        """Stop the thread and release the sockets. Safe twice."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        for sock in (self._sock, self._out):
            if sock is not None:
                sock.close()
        self._sock = self._out = None

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ---------------------------------------------------------------------------------------- truth

    def firing_of(self, time_ns: np.ndarray) -> np.ndarray:
        """The firing index of returns stamped ``time_ns`` (int64 ns on its clock)."""
        return np.round((np.asarray(time_ns, np.int64) - self.clock0_ns) / self.pattern.point_interval_ns
                        ).astype(np.int64)

    def truth(self, firing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(first, second)``: the noise-free first and second returns (N, 3) (m, LiDAR frame) of firings
        ``firing``; rows of zeros where there is none."""
        first, second, *_ = self._cast(np.asarray(firing, np.int64), noise=False)
        return first, second

    def _cast(self, firing: np.ndarray, noise: bool = True
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """First and second returns (N, 3) (m, LiDAR frame, zeros for none) and their reflectivities (N,) uint8."""
        dirs = self.pattern.directions(firing)
        R, origin = self.T_base_lidar[:3, :3], self.T_base_lidar[:3, 3]
        dirs_base = dirs @ R.T
        r1, labels1, normals1 = self.scene.cast(origin, dirs_base)
        hit1 = np.isfinite(r1) & (r1 <= MAX_RANGE_M)
        r2, labels2, normals2 = self._next_surface(origin, dirs_base, np.where(hit1, r1, np.inf))
        hit2 = np.isfinite(r2) & (r2 <= MAX_RANGE_M)
        returns, reflect = [], []
        for r, hit, labels, normals in ((r1, hit1, labels1, normals1), (r2, hit2, labels2, normals2)):
            measured = r + self._rng.normal(0.0, self.range_noise_m, len(r)) if noise and self.range_noise_m else r
            returns.append(np.where(hit[:, None], dirs * np.where(hit, measured, 0.0)[:, None], 0.0))
            cos_incidence = np.abs(np.einsum("ij,ij->i", normals, dirs_base))
            reflect.append(np.clip(label_reflectivity(labels) * (0.35 + 0.65 * cos_incidence), 0, 255).astype(np.uint8))
        return returns[0], returns[1], reflect[0], reflect[1]

    def _next_surface(self, origin: np.ndarray, dirs_base: np.ndarray, r1: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Range (m, ``inf`` for none), label and normal of the next surface facing the ray behind the one hit at
        ``r1`` (m): the ray is cast again from just behind it, and once more from behind the solid's back face."""
        r = r1.copy()
        labels, normals = np.zeros(len(r), np.int8), np.zeros((len(r), 3))
        pending = np.flatnonzero(np.isfinite(r))
        for _ in range(2):
            start = origin + dirs_base[pending] * (r[pending] + SECOND_RETURN_GAP_M)[:, None]
            step, labels[pending], normals[pending] = self.scene.cast(start, dirs_base[pending])
            r[pending] += SECOND_RETURN_GAP_M + step
            back_face = np.isfinite(step) & (np.einsum("ij,ij->i", normals[pending], dirs_base[pending]) > 0)
            pending = pending[back_face]
        r[pending] = np.inf  # still inside a solid: no second return
        return r, labels, normals

    # ---------------------------------------------------------------------------------------- packets

    def point_packets(self, first_firing: int, n_packets: int) -> bytes:
        """``n_packets`` consecutive data packets (type 2, or 4 in dual-return mode) from firing ``first_firing``,
        concatenated (each :func:`~backend.devices.livox_packets.packet_size` bytes)."""
        data_type = DATA_TYPE_DUAL_EXTEND_CARTESIAN if self.return_mode == RETURN_MODES["dual"] \
            else DATA_TYPE_EXTEND_CARTESIAN
        per_packet = DATA_TYPES[data_type][1]
        firing = first_firing + np.arange(n_packets * per_packet)
        first, second, reflect1, reflect2 = self._cast(firing)
        mm1, mm2 = np.round(first * 1000).astype(np.int32), np.round(second * 1000).astype(np.int32)
        if data_type == DATA_TYPE_DUAL_EXTEND_CARTESIAN:
            records = np.zeros((n_packets, per_packet), DUAL_EXTEND_CARTESIAN)
            for k, (mm, reflect) in enumerate(((mm1, reflect1), (mm2, reflect2))):
                one = records["returns"][:, :, k]
                one["x"], one["y"], one["z"] = (mm[:, i].reshape(n_packets, per_packet) for i in range(3))
                one["reflectivity"] = reflect.reshape(n_packets, per_packet)
        else:
            records = np.zeros((n_packets, per_packet), EXTEND_CARTESIAN)
            records["x"], records["y"], records["z"] = (mm1[:, i].reshape(n_packets, per_packet) for i in range(3))
            records["reflectivity"] = reflect1.reshape(n_packets, per_packet)
        stamps = self.clock0_ns + firing[::per_packet] * self.pattern.point_interval_ns
        return self._with_headers(data_type, stamps, records.view(np.uint8).reshape(n_packets, -1))

    def imu_packets(self, first: int, n: int) -> bytes:
        """``n`` consecutive IMU packets (type 6) from IMU sample ``first`` (at ``clock0_ns + first * 5 ms``)."""
        gravity_g = self.T_base_lidar[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # +1 g up, in the LiDAR's axes
        records = np.zeros(n, IMU_POINT)
        records["gyro"] = self.gyro_bias_rad_s + self._rng.normal(0.0, self.gyro_noise_rad_s, (n, 3))
        records["accel"] = gravity_g + self._rng.normal(0.0, self.accel_noise_g, (n, 3))
        stamps = self.clock0_ns + (first + np.arange(n)) * IMU_PERIOD_NS
        return self._with_headers(DATA_TYPE_IMU, stamps, records.view(np.uint8).reshape(n, -1))

    def expected_accel_m_s2(self) -> np.ndarray:
        """(3,) the specific force its accelerometer measures at rest (m/s², LiDAR axes)."""
        return self.T_base_lidar[:3, :3].T @ np.array([0.0, 0.0, STANDARD_GRAVITY_M_S2])

    def _with_headers(self, data_type: int, stamps: np.ndarray, bodies: np.ndarray) -> bytes:
        headers = np.zeros(len(stamps), ETH_HEADER)
        headers["version"] = self.protocol_version
        headers["slot"], headers["lidar_id"] = 1, 1
        headers["data_type"] = data_type
        headers["timestamp"] = stamps
        return np.concatenate([headers.view(np.uint8).reshape(len(stamps), -1), bodies], axis=1).tobytes()

    # ---------------------------------------------------------------------------------------- the thread

    def _run(self) -> None:
        sock, out = self._sock, self._out
        assert sock is not None and out is not None
        t0 = time.monotonic()
        next_firing = 0  # the next firing to send
        next_imu = 0
        next_broadcast = t0
        interval_ns = self.pattern.point_interval_ns
        while not self._stop.is_set():
            readable, _, _ = select.select([sock], [], [], self.burst_s)
            if readable:
                try:
                    data, sender = sock.recvfrom(2048)
                except OSError:
                    data, sender = b"", None
                if data and sender is not None and self._plugged.is_set():
                    self._answer(data, sender)
            now = time.monotonic()
            elapsed_ns = int((now - t0) * 1e9)
            due_firing = elapsed_ns // interval_ns
            due_imu = elapsed_ns // IMU_PERIOD_NS
            live = self._plugged.is_set() and self.connected and self.sampling
            if self.connected and now - self._last_heartbeat > self.heartbeat_timeout_s:
                self._disconnect()
            if not self.connected and self._plugged.is_set() and now >= next_broadcast:
                payload = BROADCAST.pack(self.broadcast_code.encode()[:16], self.device_type, 0)
                self._send(sock, Frame(CMD_TYPE_MESSAGE, 0, CMD_SET_GENERAL, CMD_BROADCAST, payload),
                           self.discovery_address)
                next_broadcast = now + 1.0
            per_packet = DATA_TYPES[DATA_TYPE_DUAL_EXTEND_CARTESIAN if self.return_mode == RETURN_MODES["dual"]
                                   else DATA_TYPE_EXTEND_CARTESIAN][1]
            behind = int(_MAX_BURST_S * 1e9 / interval_ns)
            if not live or due_firing - next_firing > behind:  # not sending, or stalled: those firings are gone
                next_firing = max(next_firing, due_firing - due_firing % per_packet)
            n_packets = (due_firing - next_firing) // per_packet
            if live and n_packets > 0:
                self._send_datagrams(out, self.point_packets(next_firing, n_packets), n_packets, self._data_address)
                self.packets_sent += n_packets
                next_firing += n_packets * per_packet
            if live and self.imu_on and due_imu > next_imu:
                n = min(due_imu - next_imu, int(_MAX_BURST_S * 1e9 / IMU_PERIOD_NS))
                self._send_datagrams(out, self.imu_packets(due_imu - n, n), n, self._imu_address)
                self.imu_packets_sent += n
            next_imu = due_imu

    def _send_datagrams(self, out: socket.socket, data: bytes, n: int, address: tuple[str, int] | None) -> None:
        size = len(data) // n
        for i in range(n):
            try:
                out.sendto(data[i * size:(i + 1) * size], address)
            except OSError:
                pass  # nobody listens (yet): a LiDAR sends regardless

    def _send(self, sock: socket.socket, frame: Frame, address: tuple[str, int] | None) -> None:
        try:
            sock.sendto(pack_frame(frame), address)
        except OSError:
            pass

    def _disconnect(self) -> None:
        self.host_address = self._data_address = self._imu_address = None
        self.sampling = False
        self.imu_on = False

    def _answer(self, data: bytes, sender: tuple[str, int]) -> None:
        """Handle one request from ``sender``."""
        try:
            request = parse_frame(data)
        except ValueError:
            return  # the firmware drops what it cannot parse
        if request.cmd_type != CMD_TYPE_REQUEST:
            return
        key = (request.cmd_set, request.cmd_id)
        if key == (CMD_SET_GENERAL, CMD_HANDSHAKE) and len(request.payload) >= HANDSHAKE.size:
            ip, data_port, cmd_port, imu_port = HANDSHAKE.unpack_from(request.payload)
            host_ip = socket.inet_ntoa(ip)
            if self.connected and self.host_address != (host_ip, cmd_port):
                self._ack(request, b"\x01", sender)  # taken by another host
                return
            self.host_address = (host_ip, cmd_port)
            self._data_address, self._imu_address = (host_ip, data_port), (host_ip, imu_port)
            self._last_heartbeat = time.monotonic()
            self._ack(request, b"\x00", sender)
            return
        if not self.connected or sender[1] != self.host_address[1]:
            self._ack(request, b"\x01", sender)
            return
        if key == (CMD_SET_GENERAL, CMD_HEARTBEAT):
            self.heartbeats += 1
            self._last_heartbeat = time.monotonic()
            if not self.drop_heartbeat_acks:
                self._ack(request, HEARTBEAT_ACK.pack(0, 1, 0, 0), sender)
        elif key == (CMD_SET_GENERAL, CMD_SAMPLING) and request.payload:
            self.sampling = request.payload[0] == 1
            self._ack(request, b"\x00", sender)
        elif key == (CMD_SET_GENERAL, CMD_DISCONNECT):
            self._ack(request, b"\x00", sender)
            self._disconnect()
        elif key == (CMD_SET_LIDAR, CMD_RETURN_MODE) and request.payload[:1] in (b"\x00", b"\x01", b"\x02"):
            self.return_mode = request.payload[0]
            self._ack(request, b"\x00", sender)
        elif key == (CMD_SET_LIDAR, CMD_IMU_PUSH) and request.payload[:1] in (b"\x00", b"\x01"):
            self.imu_on = request.payload[0] == 1
            self._ack(request, b"\x00", sender)
        else:
            self._ack(request, b"\x01", sender)

    def _ack(self, request: Frame, payload: bytes, address: tuple[str, int]) -> None:
        assert self._sock is not None
        self._send(self._sock, Frame(CMD_TYPE_ACK, request.seq, request.cmd_set, request.cmd_id, payload), address)
