"""Livox LiDARs speaking the Livox SDK 1 protocol (Horizon, Avia, Tele-15, Mid-40/70) live over UDP: driver ``"livox"``.

The wire format (data packets, control frames, CRCs) is :mod:`backend.devices.livox_packets`; this module holds the
connection and cuts the stream into frames. SDK 2 sensors (Mid-360, HAP) speak another protocol (other ports,
frames and packets) and are not supported: their data packets are refused by their protocol version.

**Connection**, as the Livox SDK makes it (``device_discovery.cpp``, ``command_channel.cpp``):

1. *Discovery* (``host=""``): the LiDAR broadcasts a message (command set 0, id 0: its broadcast code and device
   type) from its command port (65000) to UDP port 55000 once a second; the driver takes the first whose broadcast
   code matches ``broadcast_code`` (any, if empty) and talks to the address it came from. With ``host`` an IP the
   driver skips discovery and talks to ``host:lidar_port``.
2. *Handshake* (set 0, id 1): the host's IP and its data, command and IMU ports (the IMU packets come to the data
   port, as the SDK asks); the LiDAR acknowledges with return code 0.
3. Optional settings: return mode (set 1, id 6: first, strongest or dual) and IMU push at 200 Hz (set 1, id 8).
4. *Start sampling* (set 0, id 4, 1): data packets flow to the data port.
5. *Heartbeat* (set 0, id 3) from a thread every 0.8 s (sooner for short timeouts); the LiDAR drops a host that
   is silent for 3 s, and :meth:`LivoxLidar.read` raises :class:`DeviceDisconnected` when the LiDAR has not
   acknowledged a heartbeat for ``timeout_s``, or when no data packet arrived for ``timeout_s``.
6. :meth:`LivoxLidar.close` stops sampling and disconnects (set 0, id 6) without waiting for the answers.

Every command is retried three times with 0.5 s for its acknowledgement (the SDK's timeout).

**Frames.** :meth:`LivoxLidar.read` returns ``frame_time_s`` (s, of the sensor's clock) of returns: a data packet
belongs to the frame its time stamp falls in (so frames are cut at packet boundaries, 400 µs in single return), and a
frame is returned when the first packet of the next arrives. A sensor clock that jumps back (a restart) drops the
partial frame. Frames are bounded: ``frame_time_s`` at most :data:`MAX_FRAME_TIME_S` and at most
:data:`MAX_FRAME_PACKETS` packets (a frame that reaches it is returned early with ``meta["complete"] = False``).

**Samples** (``stream="points"``): ``points`` (N, 3) float64 in the LiDAR frame (x forward, y left, z up, m),
``intensity`` (N,) float32 reflectivity 0-255, ``imu`` the built-in IMU's samples that arrived with the frame (when
``imu=True``; gyro rad/s, accel m/s² converted from the g Livox sends, times s on the LiDAR's clock), ``timestamp_s``
the host clock (s since the epoch) when its last packet arrived. ``meta``: ``frame_index``, ``packets``,
``lost_packets`` (gaps in the packets' time stamps in this frame), ``malformed`` (datagrams of the wrong size so
far), ``complete``, ``sensor_time_s`` (first packet's stamp, s), ``timestamp_type`` (``"no sync"``, ``"PTP"``,
``"PPS+GPS"``, ``"PPS"``), ``data_types`` (2 single, 4 dual), ``return_mode`` (``"single"``/``"dual"``/``"mixed"``),
``protocol_version`` (5), ``broadcast_code``, ``model``, ``fov_deg`` and ``fov_elliptical`` (the model's field of
view, for :mod:`backend.devices.accumulate`), ``work_state`` and ``status_code`` (from the last heartbeat), and the
arrays ``point_time_s`` (each return's time after ``sensor_time_s``) and ``return_index`` (0 first, 1 second of a
dual-return firing).

``stream="imu"`` makes the LiDAR an IMU in the rig: each :meth:`read` returns ``frame_time_s`` of IMU samples as
``Sample.imu`` (``timestamp_s`` the first sample's time on the LiDAR's clock), the point packets skipped. A LiDAR
takes one host connection at a time, so a rig reads its points and IMU through one device (``stream="points"``
returns both) or picks one stream per device.

Bad settings are a :class:`DeviceError` from the constructor; a data packet of a protocol version other than 5 or
of a data type not read is a :class:`DeviceError` naming the version or type and what is supported.

``host="sim"`` binds 127.0.0.1 on free ports and starts the simulated endpoint registered as ``"livox"``
(:func:`~backend.devices.base.start_simulator`): an Avia (or ``model``) at the demo rig's ground-truth pose of
``sim_sensor`` ray-casting the yard, broadcasting to the driver's discovery port. :attr:`LivoxLidar.simulator` is it.
"""

from __future__ import annotations

import errno
import math
import socket
import struct
import threading
import time
from typing import Any

import numpy as np

from backend.core.accumulation import FieldOfView
from backend.core.imu import ImuSamples
from backend.devices.base import (
    CaptureDevice,
    DeviceDisconnected,
    DeviceError,
    Sample,
    register_driver,
    start_simulator,
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
    DATA_TYPE_IMU,
    DATA_TYPES,
    DISCOVERY_PORT,
    ETH_HEADER,
    HANDSHAKE,
    HEARTBEAT_ACK,
    LIDAR_COMMAND_PORT,
    LIVOX_MODELS,
    POINT_INTERVAL_NS,
    SDK1_PROTOCOL_VERSION,
    TIMESTAMP_PPS_GPS,
    TIMESTAMP_TYPES,
    Frame,
    check_data_header,
    data_headers,
    decode_imu,
    decode_points,
    pack_frame,
    packet_size,
    packet_times_ns,
    parse_frame,
)

CMD_SET_LIDAR = 1
CMD_RETURN_MODE = 6
"""LiDAR command set: set the return mode (uint8: :data:`RETURN_MODES`)."""
CMD_IMU_PUSH = 8
"""LiDAR command set: IMU push frequency (uint8: 0 off, 1 200 Hz)."""
RETURN_MODES = {"first": 0, "strongest": 1, "dual": 2}
"""``PointCloudReturnMode`` of ``livox_def.h`` (triple return is not read)."""
WORK_STATES = {0: "initialising", 1: "normal", 2: "power saving", 3: "standby", 4: "error"}

LIVOX_FOV = {
    "Avia": FieldOfView(math.radians(70.4), math.radians(77.2), elliptical=True),
    "Horizon": FieldOfView(math.radians(81.7), math.radians(25.1)),
    "Tele-15": FieldOfView(math.radians(14.5), math.radians(16.2), elliptical=True),
    "Mid-40": FieldOfView(math.radians(38.4), math.radians(38.4), elliptical=True),
    "Mid-70": FieldOfView(math.radians(70.4), math.radians(70.4), elliptical=True),
}
"""Field of view of each model in its non-repetitive pattern (the data sheets' full angles)."""
MODEL_TYPES = {name: code for code, name in LIVOX_MODELS.items() if name in LIVOX_FOV}
"""Device type code of each LiDAR model."""

MAX_FRAME_TIME_S = 1.0
"""Longest frame (s): 480,000 returns of an Avia in dual return, ~6.8 MB of packets."""
MAX_FRAME_PACKETS = 10_000
"""Most data packets in one frame (twice an Avia's dual-return second)."""
MAX_DATAGRAM_BYTES = 1500
"""Longest datagram taken (a data packet is 1362 bytes)."""
COMMAND_TIMEOUT_S = 0.5
COMMAND_TRIES = 3
HEARTBEAT_PERIOD_S = 0.8
IMU_PERIOD_NS = 5_000_000
"""The built-in IMU's sample period at 200 Hz (ns)."""
_RECV_BUFFER_BYTES = 8 * 1024 * 1024


def _check_number(name: str, value: Any, low: float, high: float, device: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not low < value <= high:
        raise DeviceError(f"{name} must be a number of seconds in ({low:g}, {high:g}], not {value!r}", device)
    return float(value)


class _FrameCutter:
    """Collects data packets of one stream (point or IMU) into frames of ``frame_time_ns`` of sensor time."""

    def __init__(self, frame_time_ns: int):
        self.frame_time_ns = frame_time_ns
        self.packets: list[bytes] = []
        self.times: list[int] = []
        self.lost = 0
        self._end: int | None = None
        self._last: int | None = None
        self._last_step: int | None = None

    def push(self, packet: bytes, t_ns: int, step_ns: int) -> tuple[list[bytes], list[int], int] | None:
        """Add a packet stamped ``t_ns`` spanning ``step_ns``; return ``(packets, times, lost)`` of the frame it
        completes, if any."""
        done = None
        if self._last is not None and t_ns < self._last:  # the sensor's clock went back: a restart
            self.reset()
        if self._end is not None and t_ns >= self._end:
            done = (self.packets, self.times, self.lost)
            self.packets, self.times, self.lost = [], [], 0
            self._end = self._end + self.frame_time_ns if t_ns < self._end + self.frame_time_ns else None
        if self._end is None:
            self._end = t_ns + self.frame_time_ns
        if self._last is not None and self._last_step:
            gap = t_ns - self._last
            if gap > 1.5 * self._last_step:
                self.lost += round(gap / self._last_step) - 1
        self.packets.append(packet)
        self.times.append(t_ns)
        self._last, self._last_step = t_ns, step_ns
        if done is None and len(self.packets) >= MAX_FRAME_PACKETS:
            done = (self.packets, self.times, self.lost)
            self.packets, self.times, self.lost, self._end = [], [], 0, None
        return done

    def reset(self) -> None:
        self.packets, self.times, self.lost = [], [], 0
        self._end = self._last = self._last_step = None


@register_driver
class LivoxLidar(CaptureDevice):
    """A Livox SDK 1 LiDAR over UDP (see the module docstring)."""

    driver = "livox"

    def __init__(self, host: str = "", broadcast_code: str = "", model: str = "Avia", frame_time_s: float = 0.1,
                 stream: str = "points", return_mode: str = "", imu: bool = True, timeout_s: float = 3.0,
                 local_ip: str = "", data_port: int = 56001, cmd_port: int = 55501,
                 discovery_port: int = DISCOVERY_PORT, lidar_port: int = LIDAR_COMMAND_PORT,
                 sim_sensor: str = "lidar_front"):
        """Settings as stored in the rig.

        Args:
            host: the LiDAR's IP; ``""`` to find it by its broadcast; ``"sim"`` for the built-in simulator.
            broadcast_code: the code on the LiDAR's label (15 characters) to connect to; ``""`` takes the first
                LiDAR heard (with ``host=""``).
            model: ``"Avia"``, ``"Horizon"``, ``"Tele-15"``, ``"Mid-40"`` or ``"Mid-70"``; checked against the
                device type the LiDAR broadcasts; sets the field of view in ``meta`` and the firing interval when the
                LiDAR is reached by IP (no broadcast).
            frame_time_s: sensor time (s) one :meth:`read` returns, in (0, :data:`MAX_FRAME_TIME_S`].
            stream: ``"points"`` (frames of returns, with the IMU samples) or ``"imu"`` (IMU samples only).
            return_mode: ``"first"``, ``"strongest"`` or ``"dual"`` to set it when connecting; ``""`` leaves it.
            imu: ask for the built-in IMU's samples at 200 Hz (always on with ``stream="imu"``).
            timeout_s: how long without data packets or heartbeat acknowledgements before :meth:`read` raises
                :class:`DeviceDisconnected` (s); also the wait for a broadcast.
            local_ip: this host's IP on the LiDAR's network, sent in the handshake; ``""`` lets the routing pick it.
            data_port, cmd_port: this host's UDP ports for data (points and IMU) and commands (the SDK's
                56001 and 55501); 0 picks free ones.
            discovery_port: UDP port the broadcasts come to (55000).
            lidar_port: the LiDAR's command port (65000), with ``host`` an IP.
            sim_sensor: with ``host="sim"``, the ``lidar3d`` sensor of the demo rig whose ground-truth mounting poses
                the simulated LiDAR.
        """
        self.host = str(host)
        self.broadcast_code = str(broadcast_code)
        self.model = model
        self.stream = stream
        self.return_mode = return_mode
        self.imu = bool(imu) or stream == "imu"
        self.local_ip = str(local_ip)
        self.data_port, self.cmd_port = int(data_port), int(cmd_port)
        self.discovery_port, self.lidar_port = int(discovery_port), int(lidar_port)
        self.sim_sensor = sim_sensor
        device = self.describe()
        self.frame_time_s = _check_number("frame_time_s", frame_time_s, 0.0, MAX_FRAME_TIME_S, device)
        self.timeout_s = _check_number("timeout_s", timeout_s, 0.0, 60.0, device)
        if model not in LIVOX_FOV:
            raise DeviceError(f"unknown Livox model {model!r}; supported (Livox SDK 1): {', '.join(LIVOX_FOV)}",
                              device)
        if stream not in ("points", "imu"):
            raise DeviceError(f"stream must be 'points' or 'imu', not {stream!r}", device)
        if return_mode and return_mode not in RETURN_MODES:
            raise DeviceError(f"return_mode must be one of {', '.join(RETURN_MODES)} or '' (leave it), not "
                              f"{return_mode!r}", device)
        self.simulator: Any = None
        """With ``host="sim"``, the simulated LiDAR while open (``unplug()``, ``replug()``, ``drop_heartbeat_acks``,
        ``protocol_version``, ``truth()``...)."""
        self.lidar_address: tuple[str, int] | None = None
        """The LiDAR's command address once connected."""
        self.device_type: int = MODEL_TYPES[model]
        self.malformed = 0
        """Datagrams dropped so far (wrong size, not a control frame)."""
        self._data: socket.socket | None = None
        self._cmd: socket.socket | None = None
        self._seq = 0
        self._buf = bytearray(MAX_DATAGRAM_BYTES + 1)
        self._heartbeat: threading.Thread | None = None
        self._stop = threading.Event()
        self._last_ack = 0.0
        self._lost_reason: str | None = None
        self._state: tuple[int, int] = (0, 0)
        self._points = _FrameCutter(round(self.frame_time_s * 1e9))
        self._imu = _FrameCutter(round(self.frame_time_s * 1e9))
        self._imu_pending: list[bytes] = []
        self._frame_index = 0
        self._timestamp_types: set[int] = set()

    def describe(self) -> str:
        if self.host == "sim":
            return f"livox {self.model} sim {self.sim_sensor}"
        where = self.host or f"broadcast {self.broadcast_code or 'any'}"
        return f"livox {self.model} {where}"

    # ---------------------------------------------------------------------------------------- connecting

    def open(self) -> None:
        """Find the LiDAR, hand-shake, configure it and start sampling and heartbeats; :class:`DeviceError` saying
        which step failed."""
        self.close()
        self._stop.clear()
        self._lost_reason = None
        self.malformed = 0
        self._points.reset()
        self._imu.reset()
        self._imu_pending = []
        simulated = self.host == "sim"
        bind_ip = "127.0.0.1" if simulated else "0.0.0.0"
        try:
            self._data = self._bind(bind_ip, 0 if simulated else self.data_port, "data")
            self._data.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _RECV_BUFFER_BYTES)
            self._cmd = self._bind(bind_ip, 0 if simulated else self.cmd_port, "command")
            if simulated or not self.host:
                self.lidar_address = self._discover(bind_ip, simulated)
            else:
                self.lidar_address = (self.host, self.lidar_port)
            self._connect(simulated)
        except BaseException:
            self.close()
            raise
        self._last_ack = time.monotonic()
        self._heartbeat = threading.Thread(target=self._heartbeat_loop, name=f"livox-heartbeat-{self.cmd_port}",
                                           daemon=True)
        self._heartbeat.start()

    def _bind(self, ip: str, port: int, what: str) -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((ip, port))
        except OSError as exc:
            sock.close()
            hint = (" — another program (Livox Viewer, a ROS livox driver, a second studio) holds it"
                    if exc.errno == errno.EADDRINUSE else "")
            raise DeviceError(f"cannot bind the {what} port udp {ip}:{port}: {exc.strerror or exc}{hint}",
                              self.describe()) from None
        return sock

    def _discover(self, bind_ip: str, simulated: bool) -> tuple[str, int]:
        """The command address of the first LiDAR whose broadcast matches; :class:`DeviceError` after
        ``max(timeout_s, 2.5)`` s without one."""
        listener = self._bind(bind_ip, 0 if simulated else self.discovery_port, "discovery")
        try:
            listener.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
            if simulated:
                self.simulator = start_simulator("livox", self.describe(), discovery_port=listener.getsockname()[1],
                                                 sensor=self.sim_sensor, model=self.model)
            heard: list[str] = []
            not_livox: list[str] = []
            deadline = time.monotonic() + max(self.timeout_s, 2.5)
            while (remaining := deadline - time.monotonic()) > 0:
                listener.settimeout(remaining)
                try:
                    data, sender = listener.recvfrom(MAX_DATAGRAM_BYTES)
                except TimeoutError:
                    break
                try:
                    frame = parse_frame(data)
                except ValueError as exc:
                    not_livox.append(str(exc))
                    continue
                if frame.cmd_set != CMD_SET_GENERAL or frame.cmd_id != CMD_BROADCAST or len(frame.payload) < 17:
                    continue
                raw_code, device_type, _ = BROADCAST.unpack(frame.payload[:BROADCAST.size].ljust(BROADCAST.size, b"\0"))
                code = raw_code.split(b"\0")[0].decode("ascii", "replace")
                if self.broadcast_code and code != self.broadcast_code:
                    if code not in heard:
                        heard.append(code)
                    continue
                model = LIVOX_MODELS.get(device_type, f"device type {device_type}")
                if device_type != MODEL_TYPES[self.model]:
                    raise DeviceError(f"the LiDAR {code} broadcasts as a {model} but the sensor is set up as "
                                      f"{self.model}; fix the model setting", self.describe())
                self.broadcast_code, self.device_type = code, device_type
                return sender[0], sender[1]
        finally:
            listener.close()
        detail = f"; heard only {', '.join(heard)}" if heard else ""
        if not_livox:
            detail += (f"; {len(not_livox)} datagram(s) were not Livox SDK 1 control frames (the first: "
                       f"{not_livox[0]})")
        wanted = f"from {self.broadcast_code} " if self.broadcast_code else ""
        port = "of the simulator" if simulated else self.discovery_port
        raise DeviceError(f"no Livox SDK 1 broadcast {wanted}on udp port {port} "
                          f"in {max(self.timeout_s, 2.5):g} s — is the LiDAR powered and on this network{detail}?",
                          self.describe())

    def _host_ip(self) -> str:
        if self.local_ip:
            return self.local_ip
        assert self.lidar_address is not None
        probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            probe.connect(self.lidar_address)  # no packet is sent: the routing picks the interface
            return probe.getsockname()[0]
        except OSError as exc:
            raise DeviceError(f"no route to the LiDAR at {self.lidar_address[0]}: {exc.strerror or exc}",
                              self.describe()) from None
        finally:
            probe.close()

    def _connect(self, simulated: bool) -> None:
        assert self._data is not None and self._cmd is not None
        data_port, cmd_port = self._data.getsockname()[1], self._cmd.getsockname()[1]
        try:
            ip = socket.inet_aton(self._host_ip())
        except OSError:
            raise DeviceError(f"local_ip {self.local_ip!r} is not an IPv4 address", self.describe()) from None
        self._command(CMD_SET_GENERAL, CMD_HANDSHAKE, HANDSHAKE.pack(ip, data_port, cmd_port, data_port), "handshake")
        if self.return_mode:
            self._command(CMD_SET_LIDAR, CMD_RETURN_MODE, bytes([RETURN_MODES[self.return_mode]]),
                          f"set return mode {self.return_mode}")
        if self.imu:
            self._command(CMD_SET_LIDAR, CMD_IMU_PUSH, b"\x01", "IMU push at 200 Hz")
        self._command(CMD_SET_GENERAL, CMD_SAMPLING, b"\x01", "start sampling")

    def _send(self, cmd_set: int, cmd_id: int, payload: bytes) -> int:
        assert self._cmd is not None and self.lidar_address is not None
        self._seq = (self._seq + 1) & 0xFFFF
        self._cmd.sendto(pack_frame(Frame(CMD_TYPE_REQUEST, self._seq, cmd_set, cmd_id, payload)), self.lidar_address)
        return self._seq

    def _command(self, cmd_set: int, cmd_id: int, payload: bytes, what: str) -> bytes:
        """Send a request and wait for its acknowledgement (retried); :class:`DeviceError` if none comes or it is
        refused. Only before the heartbeat thread runs."""
        sock = self._cmd
        assert sock is not None and self.lidar_address is not None
        where = f"{self.lidar_address[0]}:{self.lidar_address[1]}"
        for _ in range(COMMAND_TRIES):
            try:
                seq = self._send(cmd_set, cmd_id, payload)
            except OSError as exc:
                raise DeviceError(f"cannot send the {what} command to {where}: {exc.strerror or exc}",
                                  self.describe()) from None
            deadline = time.monotonic() + COMMAND_TIMEOUT_S
            while (remaining := deadline - time.monotonic()) > 0:
                sock.settimeout(remaining)
                try:
                    data = sock.recv(MAX_DATAGRAM_BYTES)
                except TimeoutError:
                    break
                except OSError:  # an ICMP port unreachable from a previous send
                    continue
                try:
                    ack = parse_frame(data)
                except ValueError:
                    self.malformed += 1
                    continue
                if ack.cmd_type == CMD_TYPE_ACK and (ack.cmd_set, ack.cmd_id, ack.seq) == (cmd_set, cmd_id, seq):
                    if not ack.payload or ack.payload[0] != 0:
                        code = ack.payload[0] if ack.payload else "none"
                        raise DeviceError(f"the LiDAR at {where} refused the {what} command (return code {code})",
                                          self.describe())
                    return ack.payload
        raise DeviceError(f"the LiDAR at {where} did not acknowledge the {what} command ({COMMAND_TRIES} tries of "
                          f"{COMMAND_TIMEOUT_S:g} s) — is it a Livox SDK 1 LiDAR, and is it connected to another "
                          "host?", self.describe())

    def _heartbeat_loop(self) -> None:
        """Send heartbeats and watch their acknowledgements until :meth:`close`."""
        sock = self._cmd
        assert sock is not None
        period = min(HEARTBEAT_PERIOD_S, self.timeout_s / 4)
        next_beat = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_beat:
                try:
                    self._send(CMD_SET_GENERAL, CMD_HEARTBEAT, b"")
                except OSError as exc:
                    self._lost_reason = f"cannot send heartbeats: {exc.strerror or exc}"
                    return
                next_beat = now + period
            sock.settimeout(max(min(next_beat - now, 0.05), 0.001))
            try:
                frame = parse_frame(sock.recv(MAX_DATAGRAM_BYTES))
            except (TimeoutError, ValueError, OSError):
                frame = None
            if frame is not None and frame.cmd_type == CMD_TYPE_ACK and frame.cmd_id == CMD_HEARTBEAT \
                    and frame.cmd_set == CMD_SET_GENERAL and len(frame.payload) >= HEARTBEAT_ACK.size:
                _, work_state, _, status = HEARTBEAT_ACK.unpack_from(frame.payload)
                self._state = (work_state, status)
                self._last_ack = time.monotonic()
            elif frame is not None and frame.cmd_type == CMD_TYPE_MESSAGE:
                pass  # pushed status messages (set 0, id 7): the heartbeat carries the same
            if time.monotonic() - self._last_ack > self.timeout_s:
                self._lost_reason = (f"the LiDAR has not acknowledged a heartbeat for {self.timeout_s:g} s (it was "
                                     "unplugged, powered off, or taken over by another host)")
                return

    # ---------------------------------------------------------------------------------------- reading

    def read(self) -> Sample:
        """The next frame; :class:`DeviceDisconnected` when the LiDAR stops answering or sending."""
        sock = self._data
        if sock is None:
            raise DeviceError("not open; call open() first", self.describe())
        view = memoryview(self._buf)
        deadline = time.monotonic() + self.timeout_s
        while True:
            if self._lost_reason is not None:
                self._points.reset()
                raise DeviceDisconnected(self._lost_reason, self.describe())
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self._points.reset()
                extra = f"; {self.malformed} malformed datagrams were ignored" if self.malformed else ""
                raise DeviceDisconnected(f"no Livox data packets on udp port {sock.getsockname()[1]} for "
                                         f"{self.timeout_s:g} s although the LiDAR answers heartbeats — was sampling "
                                         f"stopped by another program?{extra}", self.describe())
            sock.settimeout(min(remaining, 0.1))
            try:
                n = sock.recv_into(self._buf)
            except TimeoutError:
                continue
            except OSError as exc:
                raise DeviceDisconnected(f"udp socket failed: {exc}", self.describe()) from None
            sample = self._take(bytes(view[:n]))
            if sample is not None:
                return sample
            if n >= ETH_HEADER.itemsize:
                deadline = time.monotonic() + self.timeout_s

    def _take(self, packet: bytes) -> Sample | None:
        """Check one datagram and add it to its stream; the sample it completes, if any."""
        if len(packet) < ETH_HEADER.itemsize or len(packet) > MAX_DATAGRAM_BYTES:
            self.malformed += 1
            return None
        version, data_type = packet[0], packet[9]
        try:
            check_data_header(version, data_type)
        except ValueError as exc:
            raise DeviceError(f"udp port {self._data.getsockname()[1] if self._data else '?'}: {exc}",
                              self.describe()) from None
        if len(packet) != packet_size(data_type):
            self.malformed += 1
            return None
        timestamp_type = packet[8]
        self._timestamp_types.add(timestamp_type)
        if timestamp_type == TIMESTAMP_PPS_GPS:
            try:
                t_ns = int(packet_times_ns(np.frombuffer(packet[:ETH_HEADER.itemsize], ETH_HEADER))[0])
            except ValueError as exc:
                raise DeviceError(str(exc), self.describe()) from None
        else:
            t_ns = struct.unpack_from("<Q", packet, 10)[0]
        interval = POINT_INTERVAL_NS.get(self.device_type, POINT_INTERVAL_NS[0])
        if data_type == DATA_TYPE_IMU:
            if self.stream == "imu":
                done = self._imu.push(packet, t_ns, IMU_PERIOD_NS)
                return None if done is None else self._imu_sample(done[0], done[2])
            self._imu_pending.append(packet)
            return None
        if self.stream == "imu":
            return None
        done = self._points.push(packet, t_ns, DATA_TYPES[data_type][1] * interval)
        return None if done is None else self._points_sample(*done, interval)

    def _imu_samples(self, packets: list[bytes]) -> ImuSamples | None:
        if not packets:
            return None
        rows = np.frombuffer(b"".join(packets), np.uint8).reshape(len(packets), -1)
        gyro, accel = decode_imu(rows[:, ETH_HEADER.itemsize:])
        t_s = packet_times_ns(data_headers(rows)) * 1e-9
        order = np.argsort(t_s, kind="stable")
        return ImuSamples(t_s[order], gyro[order], accel[order])

    def _imu_sample(self, packets: list[bytes], lost: int) -> Sample:
        imu = self._imu_samples(packets)
        assert imu is not None
        meta = self._meta(len(packets), lost, [DATA_TYPE_IMU])
        self._frame_index += 1
        return Sample(timestamp_s=float(imu.t_s[0]), imu=imu, meta=meta)

    def _points_sample(self, packets: list[bytes], times: list[int], lost: int, interval_ns: int) -> Sample:
        groups: dict[int, list[int]] = {}
        for i, packet in enumerate(packets):
            groups.setdefault(packet[9], []).append(i)
        t0 = min(times)
        points, intensity, offsets, returns = [], [], [], []
        for data_type, rows_of_type in sorted(groups.items()):
            rows = np.frombuffer(b"".join(packets[i] for i in rows_of_type), np.uint8).reshape(len(rows_of_type), -1)
            records = decode_points(rows[:, ETH_HEADER.itemsize:], data_type, interval_ns)
            stamps = np.asarray(times, np.int64)[rows_of_type]
            points.append(records.points_m)
            intensity.append(records.reflectivity)
            offsets.append(stamps[records.packet] - t0 + records.offset_ns)
            returns.append(records.return_index)
        imu, self._imu_pending = self._imu_samples(self._imu_pending), []
        meta = self._meta(len(packets), lost, sorted(groups))
        meta.update(sensor_time_s=t0 * 1e-9, point_time_s=np.concatenate(offsets) * 1e-9,
                    return_index=np.concatenate(returns))
        self._frame_index += 1
        return Sample(timestamp_s=time.time(), points=np.concatenate(points), intensity=np.concatenate(intensity),
                      imu=imu, meta=meta)

    def _meta(self, packets: int, lost: int, data_types: list[int]) -> dict[str, Any]:
        fov = LIVOX_FOV[self.model]
        point_types = [t for t in data_types if t != DATA_TYPE_IMU]
        mode = ("dual" if point_types == [DATA_TYPE_DUAL_EXTEND_CARTESIAN] else "mixed" if len(point_types) > 1
                else "single" if point_types else "")
        work_state, status = self._state
        return {
            "frame_index": self._frame_index, "packets": packets, "lost_packets": lost, "malformed": self.malformed,
            "complete": lost == 0 and packets < MAX_FRAME_PACKETS,
            "timestamp_type": ", ".join(TIMESTAMP_TYPES.get(t, f"type {t}") for t in sorted(self._timestamp_types)),
            "data_types": data_types, "return_mode": mode, "protocol_version": SDK1_PROTOCOL_VERSION,
            "broadcast_code": self.broadcast_code, "model": self.model,
            "fov_deg": [math.degrees(fov.horizontal_rad), math.degrees(fov.vertical_rad)],
            "fov_elliptical": fov.elliptical, "work_state": WORK_STATES.get(work_state, str(work_state)),
            "status_code": status,
        }

    # ---------------------------------------------------------------------------------------- closing

    def close(self) -> None:
        """Stop heartbeats, ask the LiDAR to stop sampling and disconnect (not waiting), release the sockets and
        the simulator. Safe twice."""
        self._stop.set()
        if self._heartbeat is not None:
            self._heartbeat.join(timeout=2.0)
            self._heartbeat = None
        if self._cmd is not None:
            if self.lidar_address is not None:
                for cmd_id, payload in ((CMD_SAMPLING, b"\x00"), (CMD_DISCONNECT, b"")):
                    try:
                        self._send(CMD_SET_GENERAL, cmd_id, payload)
                    except OSError:
                        break
            self._cmd.close()
            self._cmd = None
        if self._data is not None:
            self._data.close()
            self._data = None
        if self.simulator is not None:
            self.simulator.stop()
            self.simulator = None
