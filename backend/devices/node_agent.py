"""The node agent: one sensor on its own computer, served to the studio over Zenoh.

``calib-studio node --name sn1 --device sim-cell:sn1 --connect tls/STUDIO:7447 --keys sn1.keys.pem`` opens the
device (:func:`backend.devices.device_spec.parse_device_spec`), then, as a Zenoh peer (multicast scouting off, so
it reaches only the endpoints it is given), declares under ``calib/node/sn1/<zid>/``, ``<zid>`` being its Zenoh
session's id (so the studio tells two agents that claim one name apart, and answers only the first):

- ``alive``: a liveliness token, present while the agent runs (the studio's presence list);
- ``info``: a queryable answering JSON ``{name, kind, device, sensor, rate_hz, voxel_m, intrinsics?}``
  (``sensor``: the opened device's own description, with its serial where it has one);
- ``frames``: a publisher of the latest reading, voxelised to ``voxel_m`` and compressed
  (:func:`backend.devices.cloud_codec.encode_frame`), at up to ``rate_hz``, only while someone subscribes;
  each put carries the attachment :data:`FRAME_STAMP` (sequence number, node time at sending);
- ``capture``: a queryable answering with the next full-resolution frame read after the request;
- ``clock``: a queryable answering the node's time (float64 seconds, little-endian), for the studio's
  request/reply clock-offset estimate;

and subscribes to ``refused``: the studio puts there why it refuses this agent (its name is already held by
another), and the agent stops with that message (exit 2).

With the network's keys (``--keys FILE`` or :data:`KEYS_ENV`, :mod:`backend.devices.node_keys`) every link is
mutual TLS (``tls/`` endpoints) and the name must be the one the keys were issued for; without keys the links are
plain ``tcp/`` and anyone who reaches the port can join (the studio says so).

A simulated device also answers ``calib/sim/placements`` (a query whose payload is the JSON list of table
placements) by moving its tables (``set_placements``) before it replies.

SIGTERM or SIGINT end the agent cleanly (exit 0); a bad device spec, a device that fails to open, an endpoint
Zenoh refuses, keys that cannot be read or are another node's, or the studio's refusal is an
:class:`InputError` (the CLI's one-line error, exit 2). Log lines go to stderr.
"""

from __future__ import annotations

import json
import os
import re
import signal
import struct
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from backend.core.errors import InputError, clip, shorten
from backend.devices.base import CaptureDevice, DeviceError, Sample, create_device
from backend.devices.cloud_codec import encode_frame, frame_intrinsics
from backend.devices.device_spec import parse_device_spec
from backend.devices.node_keys import KeyBundle, tls_settings

DEFAULT_PORT = 7447
"""Zenoh's usual port: the studio listens on ``tcp/127.0.0.1:7447`` unless told otherwise."""
NODE_PREFIX = "calib/node"
SIM_PLACEMENTS_KEY = "calib/sim/placements"
FRAME_STAMP = struct.Struct("<Qd")
"""Attachment of every streamed frame: sequence number (from 0), node time when it was sent (s)."""
CLOCK_REPLY = struct.Struct("<d")
"""Payload of a clock reply: the node's time (s)."""
MAX_IDLE_RATE_HZ = 30.0
"""Frames streamed per second when ``rate_hz`` is None, at most (a device that paces itself may give fewer)."""
NO_PEER_WARN_S = 5.0
"""An agent still without a link this long after it started says so in its log (s)."""
STOP_POLL_S = 0.1
"""How long an idle agent sleeps between looks at its stop flag (s); capture requests wake it at once."""
NAME_PATTERN = re.compile(r"[A-Za-z0-9_\-]{1,64}")
"""A node name: one Zenoh key chunk (no ``/``, ``*``, ``$``, ``?``, ``#``)."""
KEYS_ENV = "CALIB_NODE_KEYS"
"""Environment variable: the key bundle's path when ``--keys`` is not given."""


def node_key(name: str, zid: str, what: str) -> str:
    """The Zenoh key ``calib/node/<name>/<zid>/<what>`` (``what``: alive, info, frames, capture, clock, refused;
    ``name`` and ``zid`` may be ``*``)."""
    return f"{NODE_PREFIX}/{name}/{zid}/{what}"


def parse_node_key(key: str) -> tuple[str, str]:
    """The ``(name, zid)`` of a :func:`node_key`."""
    parts = str(key).split("/")
    return parts[2], parts[3]


def zenoh_config(listen: list[str], connect: list[str], keys: KeyBundle | None = None,
                 access_control: dict[str, Any] | None = None, max_message_bytes: int | None = None) -> zenoh.Config:
    """A peer's configuration: the given listen and connect endpoints only, multicast scouting off; with ``keys``
    mutual TLS on every link (:func:`backend.devices.node_keys.tls_settings`), with ``access_control`` Zenoh's
    ACL, with ``max_message_bytes`` the largest message the session takes in."""
    settings: dict[str, Any] = {"mode": "peer", "scouting": {"multicast": {"enabled": False}},
                                "listen": {"endpoints": list(listen)}, "connect": {"endpoints": list(connect)}}
    link: dict[str, Any] = {}
    if keys is not None:
        link["tls"] = tls_settings(keys)
    if max_message_bytes is not None:
        link["rx"] = {"max_message_size": int(max_message_bytes)}
    if link:
        settings["transport"] = {"link": link}
    if access_control is not None:
        settings["access_control"] = access_control
    return zenoh.Config.from_json5(json.dumps(settings))


def open_session(listen: list[str], connect: list[str], field_name: str, keys: KeyBundle | None = None,
                 access_control: dict[str, Any] | None = None,
                 max_message_bytes: int | None = None) -> zenoh.Session:
    """A Zenoh peer session (:func:`zenoh_config`); :class:`InputError` naming ``field_name`` and the endpoints
    if Zenoh refuses them (a malformed endpoint, a port already taken, a ``tls/`` endpoint without keys or a
    plain one with them)."""
    protocol = "tls" if keys is not None else "tcp"
    for endpoint in (*listen, *connect):
        if not isinstance(endpoint, str) or not re.fullmatch(r"[a-z0-9]+/\S+", endpoint):
            raise InputError(f"endpoint {shorten(endpoint)}: expected PROTOCOL/ADDRESS such as "
                             f"{protocol}/127.0.0.1:{DEFAULT_PORT}", field_name)
        if keys is not None and not endpoint.startswith("tls/"):
            raise InputError(f"endpoint {shorten(endpoint)}: with the network's keys every link is TLS; expected "
                             f"tls/HOST:PORT", field_name)
        if keys is None and endpoint.startswith(("tls/", "quic/")):
            raise InputError(f"endpoint {shorten(endpoint)} needs the network's keys (--keys FILE or {KEYS_ENV})",
                             field_name)
    try:
        return zenoh.open(zenoh_config(listen, connect, keys, access_control, max_message_bytes))
    except zenoh.ZError as exc:
        raise InputError(f"Zenoh refused the endpoints (listen {listen}, connect {connect}): "
                         f"{' '.join(str(exc).split())}", field_name) from None


def sample_kind(sample: Sample) -> str:
    """What the sensor is, from one of its samples: ``depth``, ``lidar`` or ``camera``."""
    if sample.depth is not None:
        return "depth"
    return "lidar" if sample.points is not None else "camera"


@dataclass
class _Pending:
    """What the agent's zenoh callbacks hand to its read loop."""

    lock: threading.Lock = field(default_factory=threading.Lock)
    queries: list[zenoh.Query] = field(default_factory=list)
    wake: threading.Event = field(default_factory=threading.Event)
    """Set when a capture request arrives, so an idle loop answers at once."""


def run_agent(name: str, device: str, connect: list[str] | None = None, listen: list[str] | None = None,
              rate_hz: float | None = None, voxel_m: float | None = 0.02,
              clock: Callable[[], float] = time.time, stop: threading.Event | None = None,
              keys: KeyBundle | None = None) -> int:
    """Serve one sensor over Zenoh until SIGTERM/SIGINT (or ``stop`` is set); returns the exit code 0.

    Args:
        name: the node's name in the rig (``sn1``): one key chunk of letters, digits, ``_`` and ``-``.
        device: a device spec (:func:`~backend.devices.device_spec.parse_device_spec`).
        connect: endpoints to connect to (the studio's ``tls/HOST:7447``, or a router's).
        listen: endpoints to listen on (none by default: the agent dials out).
        rate_hz: streamed frames per second; None: as the device delivers them (at most
            :data:`MAX_IDLE_RATE_HZ` for a device that does not pace itself).
        voxel_m: voxel edge (m) of the streamed clouds; None streams full frames. Captures are always full.
        clock: the node's clock (s since the epoch): what ``clock`` replies and frame stamps read.
        stop: ends the agent when set (for running it in a thread, where signals cannot reach it).
        keys: the node's key bundle (:func:`backend.devices.node_keys.read_bundle`), issued for ``name``; None
            joins a network without keys (``tcp/`` endpoints).

    Raises:
        InputError: a bad name, device spec, voxel size or endpoint, keys of another node, a device that cannot
            be opened, a device lost while serving, or the studio's refusal (``input`` names which).
    """
    if not isinstance(name, str) or not NAME_PATTERN.fullmatch(name):
        raise InputError(f"node name {shorten(name)}: expected 1-64 letters, digits, '_' or '-'", "name")
    if rate_hz is not None and not rate_hz > 0:
        raise InputError(f"rate {rate_hz!r} Hz: expected a positive number of frames per second", "rate")
    if voxel_m is not None and not voxel_m > 0:
        raise InputError(f"voxel size {voxel_m!r} m: expected a positive number of metres", "voxel")
    if keys is not None and keys.name != name:
        raise InputError(f"{keys.source} holds node {keys.name}'s keys; this node is named {name} (each node "
                         f"joins with the keys issued for its name)", "keys")
    settings = parse_device_spec(device)
    stop = stop or threading.Event()
    restore = _stop_on_signals(stop)
    try:
        session = open_session(list(listen or []), list(connect or []), "connect", keys)
        try:
            sensor = _open_device(settings, device)
            try:
                agent = _Agent(name, device, sensor, session, rate_hz, voxel_m, clock, _read(sensor, device), stop)
                _log(name, f"serving {sensor.describe()} ({agent.info['kind']}) on {agent.endpoints()}")
                agent.serve()
                if agent.refusal is not None:
                    raise InputError(agent.refusal, "name")
            finally:
                sensor.close()
        finally:
            session.close()
    finally:
        restore()
    _log(name, "stopped")
    return 0


PARENT_PID_ENV = "CALIB_STUDIO_NODE_PARENT"
"""Environment variable: the pid of the process that started the agent and whose end ends it too."""
PARENT_POLL_S = 0.5
"""How often (s) an agent started by a studio looks whether that studio still runs."""


def stop_with_parent(parent_pid: int, stop: threading.Event) -> threading.Thread:
    """Set ``stop`` once this process's parent is no longer ``parent_pid`` (it ended and the process was
    re-parented), looking every :data:`PARENT_POLL_S` (a daemon thread).

    The agents a studio starts also carry Linux's parent-death signal, but that can be lost in the agent's
    start-up (seen once, in a CI dry run under load): this needs no signal at all."""
    def follow() -> None:
        while not stop.wait(PARENT_POLL_S):
            if os.getppid() != parent_pid:
                _log("agent", f"its parent {parent_pid} has ended: stopping")
                stop.set()

    thread = threading.Thread(target=follow, name="node-agent-parent", daemon=True)
    thread.start()
    return thread


def _stop_on_signals(stop: threading.Event) -> Callable[[], None]:
    """Make SIGTERM and SIGINT set ``stop`` (in the main thread only); returns what puts the old handlers back."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGTERM, signal.SIGINT)}

    def restore() -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)

    return restore


def _open_device(settings: dict[str, Any], spec: str) -> CaptureDevice:
    """The opened device; its own error as an :class:`InputError` naming the spec."""
    try:
        sensor = create_device(settings)
        sensor.open()
    except DeviceError as exc:
        raise InputError(f"cannot open {shorten(spec)}: {exc}", "device") from None
    return sensor


def _read(sensor: CaptureDevice, spec: str) -> Sample:
    try:
        return sensor.read()
    except DeviceError as exc:
        raise InputError(f"{shorten(spec)} stopped delivering: {exc}", "device") from None


class _Agent:
    """The declared Zenoh entities of one node and its read-publish-answer loop."""

    def __init__(self, name: str, spec: str, sensor: CaptureDevice, session: zenoh.Session, rate_hz: float | None,
                 voxel_m: float | None, clock: Callable[[], float], first: Sample, stop: threading.Event):
        self.name, self.spec, self.sensor, self.session, self.stop = name, spec, sensor, session, stop
        self.rate_hz, self.voxel_m, self.clock = rate_hz, voxel_m, clock
        self.pending = _Pending()
        self.sequence = 0
        self.refusal: str | None = None
        """Why the studio refused this agent (it then stops), else None."""
        self.info: dict[str, Any] = {"name": name, "kind": sample_kind(first), "device": spec,
                                     "sensor": sensor.describe(), "rate_hz": rate_hz, "voxel_m": voxel_m}
        intrinsics = None if first.depth is None else frame_intrinsics(first.depth, first.meta)
        if intrinsics is not None:
            self.info["intrinsics"] = intrinsics.to_dict()
        zid = str(session.zid())
        self.publisher = session.declare_publisher(node_key(name, zid, "frames"))
        self.entities = [
            self.publisher,
            session.declare_queryable(node_key(name, zid, "info"), self._answer_info),
            session.declare_queryable(node_key(name, zid, "clock"), self._answer_clock),
            session.declare_queryable(node_key(name, zid, "capture"), self._queue_capture),
            session.declare_subscriber(node_key(name, zid, "refused"), self._refused),
        ]
        if hasattr(sensor, "set_placements"):
            self.entities.append(session.declare_queryable(SIM_PLACEMENTS_KEY, self._apply_placements))
        self.token = session.liveliness().declare_token(node_key(name, zid, "alive"))

    def endpoints(self) -> str:
        return ", ".join(str(link.dst) for link in self.session.info.links()) or "no peer yet"

    def serve(self) -> None:
        """Until ``stop`` is set: once a period, read the device if a capture waits or someone subscribes (an
        idle node costs nothing), answer the captures asked before the read, and stream the frame."""
        stop = self.stop
        period_s = 1.0 / (self.rate_hz or MAX_IDLE_RATE_HZ)
        next_s = time.monotonic()
        lonely_since_s: float | None = time.monotonic()
        try:
            while not stop.is_set():
                if lonely_since_s is not None:
                    lonely_since_s = self._warn_when_alone(lonely_since_s)
                with self.pending.lock:
                    queries, self.pending.queries = self.pending.queries, []
                    self.pending.wake.clear()
                streaming = self.publisher.matching_status
                if queries or streaming:
                    self._read_and_send(queries, streaming)
                next_s = max(next_s + period_s, time.monotonic())
                if not streaming:  # a capture request wakes the loop at once
                    next_s = time.monotonic() + STOP_POLL_S
                self.pending.wake.wait(max(0.0, next_s - time.monotonic()))
        finally:
            self.token.undeclare()
            for entity in self.entities:
                entity.undeclare()
            with self.pending.lock:
                self._refuse(self.pending.queries, f"node {self.name} is stopping")

    def _warn_when_alone(self, since_s: float) -> float | None:
        """Log once when no link has opened :data:`NO_PEER_WARN_S` after the start (the studio is not there, or
        refuses this node's keys); None once there is a link or the warning is out."""
        if any(True for _ in self.session.info.links()):
            return None
        if time.monotonic() - since_s < NO_PEER_WARN_S:
            return since_s
        _log(self.name, f"no link after {NO_PEER_WARN_S:g} s: is the studio listening at the --connect endpoint, "
                        f"and were this node's keys made for its network?")
        return None

    def _read_and_send(self, queries: list[zenoh.Query], streaming: bool) -> None:
        """One reading: the answer to every waiting capture, and a streamed frame."""
        try:
            sample = _read(self.sensor, self.spec)
        except InputError as exc:
            self._refuse(queries, f"node {self.name}: {exc.message}")
            raise
        sample.meta["node_time_s"] = self.clock()
        for query in queries:
            self._answer_capture(query, sample)
        if streaming:
            self._publish(sample)

    @staticmethod
    def _refuse(queries: list[zenoh.Query], message: str) -> None:
        for query in queries:
            query.reply_err(message)
            query.drop()

    def _publish(self, sample: Sample) -> None:
        """Stream one frame (voxelised unless ``voxel_m`` is None)."""
        payload = encode_frame(sample, self.voxel_m)
        self.publisher.put(payload, attachment=FRAME_STAMP.pack(self.sequence, self.clock()))
        self.sequence += 1

    def _refused(self, message: zenoh.Sample) -> None:
        """The studio refuses this agent: log why and stop (the agent then exits with it)."""
        self.refusal = f"the studio refused node {self.name}: {clip(message.payload.to_string(), 300)}"
        _log(self.name, self.refusal)
        self.stop.set()
        self.pending.wake.set()

    def _answer_info(self, query: zenoh.Query) -> None:
        query.reply(query.key_expr, json.dumps(self.info))

    def _answer_clock(self, query: zenoh.Query) -> None:
        query.reply(query.key_expr, CLOCK_REPLY.pack(self.clock()))

    def _queue_capture(self, query: zenoh.Query) -> None:
        """Keep the query for the read loop, which answers it with the next frame (taken after it arrived)."""
        with self.pending.lock:
            self.pending.queries.append(query)
            self.pending.wake.set()

    def _answer_capture(self, query: zenoh.Query, sample: Sample) -> None:
        try:
            query.reply(query.key_expr, encode_frame(sample, None))
        except InputError as exc:
            query.reply_err(f"node {self.name}: {exc.message}")
        finally:
            query.drop()

    def _apply_placements(self, query: zenoh.Query) -> None:
        """Move a simulated device's tables (the query's payload: a JSON list of ``{table, centre_xy_m,
        yaw_deg}``) before answering, so a capture asked after the studio's request returns sees them."""
        try:
            rows = json.loads(query.payload.to_bytes() if query.payload is not None else b"null")
            if not isinstance(rows, list):
                raise ValueError("expected a JSON list of table placements")
            self.sensor.set_placements(rows)
        except (InputError, DeviceError, ValueError, TypeError, KeyError) as exc:
            query.reply_err(f"node {self.name}: table placements refused: {exc}")
        else:
            _log(self.name, f"tables moved: {[row.get('table') for row in rows if isinstance(row, dict)]}")
            query.reply(query.key_expr, self.name)
        finally:
            query.drop()


def _log(name: str, message: str) -> None:
    print(f"node {name}: {message}", file=sys.stderr, flush=True)
