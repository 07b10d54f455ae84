"""The studio's side of a sensor network over Zenoh: which nodes are there, their clocks, streams and captures.

:class:`NodeNetwork` opens one Zenoh peer session (listening on ``tcp/127.0.0.1:7447`` unless told otherwise;
multicast scouting off) that the node agents (:mod:`backend.devices.node_agent`) connect to. With the network's
keys (:class:`~backend.devices.node_keys.NetworkKeys`) it listens on ``tls/`` with mutual authentication and
Zenoh's access control: only peers holding keys the network issued get a link, and each speaks only under its
own name. It keeps:

- **presence** from the agents' liveliness tokens (a subscriber with history, so nodes already there count):
  a node appears, its ``info`` and clock are fetched in the background, and it disappears when its agent ends
  or its computer drops off (Zenoh closes the link). A name belongs to the first agent (Zenoh session) that
  claims it: a second agent claiming it while the first is there is refused (told so, named in the node's
  status and logged) and nothing of it is taken in. A node that comes back with another device or sensor serial
  is *held*: its captures wait until :meth:`NodeNetwork.confirm_device`;
- **clock offsets** from request/reply stamps, NTP style: ``offset = t_node - (t_send + t_recv) / 2`` for the
  round with the smallest round-trip time (its error is at most half that RTT);
- **bandwidth** and frame rate per node over a sliding window of its stream, with dropped frames counted
  from the stream's sequence numbers and the latency from the node's send stamps;
- the latest streamed frame per node, decoded only when asked for (:meth:`NodeNetwork.latest_preview`).

:meth:`NodeNetwork.capture` asks one node for a full frame; a node that is gone, or goes during the request,
is an :class:`InputError` naming it; :meth:`NodeNetwork.capture_all` keeps every frame that arrived and names
each node that failed. :class:`NetworkNode` (driver ``node``) makes a node's sensor a rig sensor like a local one.
"""

from __future__ import annotations

import collections
import dataclasses
import json
import logging
import queue
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from backend.core.depth_cell import TablePlacement
from backend.core.errors import InputError, clip, shorten
from backend.core.limits import MAX_NODE_FRAME_MB
from backend.devices.base import CaptureDevice, DeviceDisconnected, DeviceError, Sample, register_driver
from backend.devices.cloud_codec import decode_frame
from backend.devices.node_agent import (
    CLOCK_REPLY,
    DEFAULT_PORT,
    FRAME_STAMP,
    SIM_PLACEMENTS_KEY,
    node_key,
    open_session,
    parse_node_key,
)
from backend.devices.node_keys import NetworkKeys, studio_access_control

log = logging.getLogger(__name__)

DEFAULT_LISTEN = f"tcp/127.0.0.1:{DEFAULT_PORT}"
WINDOW_S = 5.0
"""Sliding window (s) of the bandwidth, frame-rate and latency figures (bytes and frames in it / WINDOW_S)."""
CLOCK_WARN_S = 0.5
"""A node whose clock is further off than this (s) is warned about."""
CLOCK_ROUNDS = 8
CLOCK_MAX_AGE_S = 60.0
"""A capture re-estimates a clock offset older than this (s): a node's clock may be stepped meanwhile."""
QUERY_POLL_S = 0.05
"""How often a waiting capture looks whether its node is still there (s)."""


@dataclass
class NodeStatus:
    """What the studio knows of one node (times are the studio's clock, s since the epoch)."""

    name: str
    alive: bool
    kind: str | None = None
    """``depth``, ``lidar`` or ``camera`` (from the node's info; None until it answered)."""
    device: str | None = None
    """The node's device spec, e.g. ``sim-cell:sn1``."""
    zid: str | None = None
    """The Zenoh session id of the agent that holds the name."""
    refused: list[str] = field(default_factory=list)
    """Zenoh ids of other agents claiming this name while it is held, refused."""
    held: str | None = None
    """Why the node's captures wait for the user (its device changed), else None."""
    first_seen_s: float = 0.0
    last_seen_s: float = 0.0
    """Last liveliness change or streamed frame."""
    clock_offset_s: float | None = None
    """Node clock minus studio clock (s; positive: the node is ahead); None until estimated."""
    clock_rtt_s: float | None = None
    """Round-trip time of the best clock round (s): the offset is good to half of it."""
    clock_checked_s: float | None = None
    """When the offset was estimated (studio clock, s)."""
    bandwidth_bps: float = 0.0
    """Bytes per second of its stream over the last :data:`WINDOW_S` (B/s, not bits)."""
    frames: int = 0
    """Streamed frames received since it appeared."""
    rate_hz: float = 0.0
    """Streamed frames per second over the last :data:`WINDOW_S`."""
    dropped: int = 0
    """Streamed frames the node sent that never arrived (gaps in its sequence numbers)."""
    latency_s: float | None = None
    """Median stream latency over the window (s): studio receive time minus the node's send stamp, corrected by
    the clock offset."""
    info: dict[str, Any] = field(default_factory=dict)
    """The node's ``info`` reply (name, kind, device, rate_hz, voxel_m, intrinsics)."""
    warnings: list[str] = field(default_factory=list)
    """E.g. ``node sn3's clock is 12.4 s ahead``."""


@dataclass(frozen=True)
class ClockEstimate:
    """One node's clock against the studio's, from ``rounds`` request/reply exchanges."""

    node: str
    offset_s: float
    """Node minus studio (s)."""
    rtt_s: float
    """Round trip of the round the offset comes from (s); the offset's error is at most half of it."""
    rounds: int
    warning: str | None = None


@dataclass
class _Stream:
    """The receiving end of one node's stream."""

    window: collections.deque = field(default_factory=collections.deque)
    """(studio receive time s, bytes, latency s) of the frames in the last :data:`WINDOW_S`."""
    first_sequence: int | None = None
    last_sequence: int = -1
    received: int = 0
    latest: bytes | None = None
    latest_preview: Sample | None = None


class NodeNetwork:
    """The studio's Zenoh session with the node agents; thread-safe."""

    def __init__(self, listen: list[str] | None = None, connect: list[str] | None = None,
                 keys: NetworkKeys | None = None):
        """``listen``: endpoints the agents connect to (default ``tcp/127.0.0.1:7447``, ``tls/...`` with keys);
        ``connect``: endpoints to connect to (agents that listen, or a Zenoh router); ``keys``: the network's keys
        (None: no authentication, anyone who reaches the port joins)."""
        self.keys = keys
        default = DEFAULT_LISTEN if keys is None else DEFAULT_LISTEN.replace("tcp/", "tls/", 1)
        self.listen = [default] if listen is None else list(listen)
        self.connect = list(connect or [])
        self._identities: dict[str, tuple[str | None, str | None]] = {}
        """Per node name, the (device spec, sensor) it first came with: a change holds its captures."""
        self._session: zenoh.Session | None = None
        self._entities: list[Any] = []
        self._lock = threading.Lock()
        self._nodes: dict[str, NodeStatus] = {}
        self._streams: dict[str, _Stream] = {}
        self._change_callbacks: list[Callable[[NodeStatus], None]] = []
        self._frame_callbacks: list[Callable[[str, int, float | None], None]] = []
        self._jobs: queue.Queue[tuple[str, str, str] | None] = queue.Queue()
        """(``info`` or ``refuse``, node name, agent's Zenoh id) for the background worker."""
        self._worker: threading.Thread | None = None

    # -- lifetime

    def open(self) -> None:
        """Open the session and start watching presence and streams; :class:`InputError` (``listen``) if Zenoh
        refuses the endpoints (e.g. the port is taken)."""
        if self._session is not None:
            return
        keys = self.keys
        self._session = open_session(self.listen, self.connect, "listen", None if keys is None else keys.studio,
                                     None if keys is None else studio_access_control(list(keys.nodes)),
                                     max_message_bytes=MAX_NODE_FRAME_MB.value() * 1_000_000 + FRAME_SLACK_BYTES)
        _OPEN.append(self)
        self._worker = threading.Thread(target=self._work, name="node-network", daemon=True)
        self._worker.start()
        liveliness = self._session.liveliness()
        self._entities = [
            liveliness.declare_subscriber(node_key("*", "*", "alive"), self._on_liveliness, history=True),
            self._session.declare_subscriber(node_key("*", "*", "frames"), self._on_frame),
        ]

    def close(self) -> None:
        """Stop watching and close the session. Safe to call twice."""
        if self._session is None:
            return
        for entity in self._entities:
            entity.undeclare()
        self._jobs.put(None)
        if self._worker is not None:
            self._worker.join(timeout=5)
        self._session.close()
        self._session, self._entities, self._worker = None, [], None
        if self in _OPEN:
            _OPEN.remove(self)

    def __enter__(self) -> NodeNetwork:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- presence and status

    @property
    def secure(self) -> bool:
        """Whether links need the network's keys (mutual TLS and access control)."""
        return self.keys is not None

    def admitted(self) -> list[str]:
        """The node names the network's keys admit ([] without keys: any name)."""
        return [] if self.keys is None else list(self.keys.nodes)

    def nodes(self) -> list[NodeStatus]:
        """Every node seen since :meth:`open`, alive or gone, by name (copies, with the window's figures)."""
        now = time.time()
        with self._lock:
            return [self._status(name, now) for name in sorted(self._nodes)]

    def is_alive(self, node: str) -> bool:
        """Whether ``node`` is on the network now."""
        with self._lock:
            status = self._nodes.get(node)
            return status is not None and status.alive

    def on_change(self, callback: Callable[[NodeStatus], None]) -> None:
        """Call ``callback(status)`` when a node appears, disappears, or its info or clock estimate arrives (from a
        network thread: keep it short)."""
        self._change_callbacks.append(callback)

    def on_frame(self, callback: Callable[[str, int, float | None], None]) -> None:
        """Call ``callback(node, n_bytes, latency_s)`` for every streamed frame received (on a Zenoh thread: keep
        it short); ``latency_s`` is None until the node's clock offset is known."""
        self._frame_callbacks.append(callback)

    def latest_preview(self, node: str) -> Sample | None:
        """The node's last streamed (voxelised) frame, decoded, or None if none arrived."""
        with self._lock:
            stream = self._streams.get(node)
            if stream is None or stream.latest is None:
                return None
            if stream.latest_preview is not None:
                return stream.latest_preview
            data = stream.latest
        preview = decode_frame(data, source=f"frame from node {node}")
        preview.meta["node"] = node
        with self._lock:
            if stream.latest is data:
                stream.latest_preview = preview
        return preview

    # -- requests

    def estimate_clock(self, node: str, rounds: int = CLOCK_ROUNDS) -> ClockEstimate:
        """The node's clock offset from ``rounds`` clock requests (the round with the smallest round trip); kept
        in its status, with a warning when it is more than :data:`CLOCK_WARN_S` off."""
        session, zid = self._require_node(node)
        best: tuple[float, float] | None = None
        for _ in range(max(1, rounds)):
            sent_s = time.time()
            replies = list(session.get(node_key(node, zid, "clock"), timeout=2.0))
            received_s = time.time()
            for reply in replies:
                if reply.ok is not None and len(payload := reply.ok.payload.to_bytes()) == CLOCK_REPLY.size:
                    (node_s,) = CLOCK_REPLY.unpack(payload)
                    rtt_s = received_s - sent_s
                    if best is None or rtt_s < best[1]:
                        best = (node_s - (sent_s + received_s) / 2, rtt_s)
        if best is None:
            raise InputError(f"node {node} did not answer its clock requests", node, status_code=503)
        offset_s, rtt_s = best
        warning = None
        if abs(offset_s) > CLOCK_WARN_S:
            warning = f"node {node}'s clock is {abs(offset_s):.1f} s {'ahead' if offset_s > 0 else 'behind'}"
        with self._lock:
            status = self._nodes.get(node)
            if status is not None:
                status.clock_offset_s, status.clock_rtt_s, status.clock_checked_s = offset_s, rtt_s, time.time()
                status.warnings = [w for w in status.warnings if "'s clock is" not in w] + ([warning] if warning
                                                                                           else [])
        self._changed(node)
        return ClockEstimate(node, offset_s, rtt_s, max(1, rounds), warning)

    def capture(self, node: str, timeout_s: float = 10.0) -> Sample:
        """One full-resolution frame of ``node`` (taken after the request reached it).

        ``meta`` gets ``node``, ``node_time_s`` (the node's clock when it read the frame), ``studio_time_s``
        (the same instant on the studio's clock, by the clock offset), ``clock_offset_s`` and ``capture_s``
        (request to decoded frame); ``timestamp_s`` is ``studio_time_s``. Raises :class:`InputError` naming the
        node when it is not on the network, is held (its device changed: 409), disappears while asked, refuses,
        does not answer within ``timeout_s``, or sends a frame over the limits (nothing of it is kept).
        """
        session, zid = self._require_node(node)
        with self._lock:
            held = self._nodes[node].held
            offset_s, checked_s = self._nodes[node].clock_offset_s, self._nodes[node].clock_checked_s
        if held is not None:
            raise InputError(held, node, status_code=409)
        if offset_s is None or checked_s is None or time.time() - checked_s > CLOCK_MAX_AGE_S:
            offset_s = self.estimate_clock(node).offset_s
        done = threading.Event()
        replies: list[zenoh.Reply] = []
        started_s = time.time()
        session.get(node_key(node, zid, "capture"), zenoh.handlers.Callback(replies.append, done.set),
                    timeout=timeout_s)
        while not done.wait(QUERY_POLL_S):
            if not self.is_alive(node):
                raise InputError(f"node {node} disappeared during the capture", node, status_code=503)
        ok = [reply.ok for reply in replies if reply.ok is not None]
        if not ok:
            errors = [reply.err.payload.to_string() for reply in replies if reply.err is not None]
            if errors:
                raise InputError(f"node {node} refused the capture: {shorten(errors[0])}", node, status_code=503)
            if time.time() - started_s < timeout_s:  # Zenoh ended the query early: the node's link closed
                raise InputError(f"node {node} disappeared during the capture", node, status_code=503)
            raise InputError(f"node {node} did not answer the capture within {timeout_s:g} s", node,
                             status_code=504)
        data = ok[0].payload.to_bytes()
        if (refusal := _oversized(node, len(data))) is not None:
            raise InputError(refusal, node, status_code=413)
        sample = decode_frame(data, source=f"capture from node {node}")
        node_time_s = float(sample.meta.get("node_time_s", sample.timestamp_s))
        sample.meta.update(node=node, node_time_s=node_time_s, studio_time_s=node_time_s - offset_s,
                           clock_offset_s=offset_s, capture_s=time.time() - started_s)
        sample.timestamp_s = node_time_s - offset_s  # on the studio's clock, like every local sensor's
        return sample

    def capture_all(self, nodes: Iterable[str], timeout_s: float = 10.0
                    ) -> tuple[dict[str, Sample], dict[str, str]]:
        """A frame from each of ``nodes`` at once: (frames by node, failure message by node). A node that fails
        costs only its own frame: every frame that arrived is returned."""
        names = list(dict.fromkeys(nodes))
        frames: dict[str, Sample] = {}
        failures: dict[str, str] = {}
        if not names:
            return frames, failures
        with ThreadPoolExecutor(max_workers=len(names), thread_name_prefix="capture") as pool:
            futures = {name: pool.submit(self.capture, name, timeout_s) for name in names}
            for name, future in futures.items():
                try:
                    frames[name] = future.result()
                except InputError as exc:
                    failures[name] = exc.message
        return frames, failures

    def set_sim_placements(self, placements: list[TablePlacement], timeout_s: float = 10.0) -> list[str]:
        """Move the tables of every simulated node (a ``calib/sim/placements`` query to all of them); returns
        once each has moved them (so a capture asked next sees them): the names of the nodes that did.
        :class:`InputError` (``placements``) naming the nodes that refused them."""
        rows = [dataclasses.asdict(placement) for placement in placements]
        replies = self._open_session().get(SIM_PLACEMENTS_KEY, payload=json.dumps(rows), timeout=timeout_s,
                                           target=zenoh.QueryTarget.ALL,
                                           consolidation=zenoh.ConsolidationMode.NONE)
        moved, refused = [], []
        for reply in replies:
            if reply.ok is not None:
                moved.append(reply.ok.payload.to_string())
            else:
                refused.append(reply.err.payload.to_string())
        if refused:
            raise InputError("; ".join(refused), "placements")
        return sorted(moved)

    # -- internals

    def _open_session(self) -> zenoh.Session:
        if self._session is None:
            raise InputError("the node network is not open", "network", status_code=409)
        return self._session

    def confirm_device(self, node: str) -> NodeStatus:
        """The user confirms that ``node``'s new device is meant: its captures no longer wait (404 for a node
        never seen, 409 for one that is not held)."""
        with self._lock:
            status = self._nodes.get(node)
            if status is None:
                raise InputError(f"node {clip(str(node), 64)} was never on the network", str(node), status_code=404)
            if status.held is None:
                raise InputError(f"node {node} has no device change to confirm", node, status_code=409)
            self._identities[node] = _identity(status.info)
            status.warnings = [w for w in status.warnings if w != status.held]
            status.held = None
        log.warning("node %s: its new device %s was confirmed by the user", node, status.device)
        self._changed(node)
        return next(s for s in self.nodes() if s.name == node)

    def _require_node(self, node: str) -> tuple[zenoh.Session, str]:
        """The session and the Zenoh id of the agent holding ``node``'s name."""
        session = self._open_session()
        with self._lock:
            status = self._nodes.get(node)
            known = sorted(name for name, s in self._nodes.items() if s.alive)
        if status is None:
            raise InputError(f"node {clip(str(node), 64)} is not on the network; nodes present: "
                             f"{', '.join(known) or 'none'}", str(node), status_code=404)
        if not status.alive or status.zid is None:
            raise InputError(f"node {node} left the network {time.time() - status.last_seen_s:.1f} s ago", node,
                             status_code=503)
        return session, status.zid

    def _status(self, name: str, now: float) -> NodeStatus:
        """A copy of the node's status with its window's bandwidth, rate and latency (lock held)."""
        status = dataclasses.replace(self._nodes[name], info=dict(self._nodes[name].info),
                                     warnings=list(self._nodes[name].warnings))
        stream = self._streams.get(name)
        if stream is not None:
            _trim(stream.window, now)
            status.bandwidth_bps = sum(n for _, n, _ in stream.window) / WINDOW_S
            status.rate_hz = len(stream.window) / WINDOW_S
            latencies = [lat for _, _, lat in stream.window if lat is not None]
            status.latency_s = float(np.median(latencies)) if latencies else None
            status.frames = stream.received
            if stream.first_sequence is not None:
                status.dropped = max(0, stream.last_sequence - stream.first_sequence + 1 - stream.received)
        return status

    def _on_liveliness(self, message: zenoh.Sample) -> None:
        """An agent's token appeared (PUT) or went (DELETE). The name goes to the first agent claiming it; another
        claiming it meanwhile is refused."""
        name, zid = parse_node_key(str(message.key_expr))
        now = time.time()
        alive = message.kind == zenoh.SampleKind.PUT
        with self._lock:
            status = self._nodes.get(name)
            if status is not None and status.alive and status.zid != zid:
                if alive and zid not in status.refused:  # a second agent claims a name that is held
                    status.refused.append(zid)
                    self._jobs.put(("refuse", name, zid))
                elif not alive and zid in status.refused:
                    status.refused.remove(zid)  # its refusal stays among the warnings
                refused = True
            else:
                refused = False
                if status is None or (alive and not status.alive):
                    status = self._nodes[name] = NodeStatus(name, True, zid=zid, first_seen_s=now)
                    self._streams[name] = _Stream()
                status.alive, status.last_seen_s = alive, now
        if alive and not refused:
            self._jobs.put(("info", name, zid))  # info and clock, off the Zenoh thread
        self._changed(name)

    def _on_frame(self, message: zenoh.Sample) -> None:
        """One streamed frame of the agent holding its name: count it, keep its bytes (decoded only on request);
        a frame over :data:`~backend.core.limits.MAX_NODE_FRAME_MB` is refused and named in the node's status."""
        received_s = time.time()
        name, zid = parse_node_key(str(message.key_expr))
        data = message.payload.to_bytes()
        latency_s = None
        refusal = _oversized(name, len(data))
        with self._lock:
            status, stream = self._nodes.get(name), self._streams.get(name)
            if status is None or stream is None or status.zid != zid:
                return
            if refusal is not None:
                status.warnings = [w for w in status.warnings if "-byte frame" not in w] + [refusal]
                return
            attachment = message.attachment
            if attachment is not None and len(stamp := attachment.to_bytes()) == FRAME_STAMP.size:
                sequence, sent_node_s = FRAME_STAMP.unpack(stamp)
                if stream.first_sequence is None or sequence < stream.last_sequence:  # first, or agent restarted
                    stream.first_sequence, stream.received, stream.last_sequence = sequence, 0, sequence
                stream.last_sequence = max(stream.last_sequence, sequence)
                if status.clock_offset_s is not None:
                    latency_s = received_s - (sent_node_s - status.clock_offset_s)
            stream.received += 1
            stream.window.append((received_s, len(data), latency_s))
            _trim(stream.window, received_s)
            stream.latest, stream.latest_preview = data, None
            status.last_seen_s = received_s
        for callback in self._frame_callbacks:
            callback(name, len(data), latency_s)

    def _work(self) -> None:
        """Background: fetch each new node's info and clock offset, or tell a refused agent why; then report the
        change."""
        while (job := self._jobs.get()) is not None:
            what, name, zid = job
            if what == "refuse":
                self._refuse(name, zid)
                continue
            if not self.is_alive(name):
                continue
            try:
                info = self._fetch_info(name, zid)
                self._check_identity(name, info)
                self.estimate_clock(name)
            except InputError as exc:
                with self._lock:
                    self._nodes[name].warnings.append(exc.message)
                self._changed(name)

    def _refuse(self, name: str, zid: str) -> None:
        """Name the second agent claiming ``name`` in the node's status and the log, and tell it (it stops)."""
        with self._lock:
            status = self._nodes.get(name)
            if status is None or zid not in status.refused:
                return
            why = (f"another agent (Zenoh id {zid}) claims node name {name}, held since "
                   f"{time.strftime('%H:%M:%S', time.localtime(status.first_seen_s))} by {status.zid}: refused; "
                   f"stop it or give it its own --name")
            status.warnings.append(why)
        log.warning("node network: %s", why)
        self._open_session().put(node_key(name, zid, "refused"), why)
        self._changed(name)

    def _check_identity(self, name: str, info: dict[str, Any]) -> None:
        """Keep the node's info; hold its captures when it comes back with another device or sensor than the one
        it first came with."""
        identity = _identity(info)
        with self._lock:
            status = self._nodes[name]
            status.info = info
            status.kind, status.device = info.get("kind"), info.get("device")
            first = self._identities.setdefault(name, identity)
            if first != identity:
                status.held = (f"node {name}'s device changed from {_identity_text(first)} to "
                               f"{_identity_text(identity)}: its captures wait until you confirm the change")
                status.warnings.append(status.held)
        if first != identity:
            log.warning("node network: %s", status.held)

    def _fetch_info(self, name: str, zid: str) -> dict[str, Any]:
        for reply in self._open_session().get(node_key(name, zid, "info"), timeout=5.0):
            if reply.ok is not None:
                try:
                    info = json.loads(reply.ok.payload.to_bytes())
                except ValueError:
                    info = None
                if isinstance(info, dict):
                    return info
        raise InputError(f"node {name} did not answer its info request", name, status_code=503)

    def _changed(self, name: str) -> None:
        with self._lock:
            if name not in self._nodes:
                return
            status = self._status(name, time.time())
        for callback in self._change_callbacks:
            callback(status)


@register_driver
class NetworkNode(CaptureDevice):
    """A sensor on another computer, read through its node agent: each :meth:`read` is a full-frame capture.

    A rig sensor whose ``device`` is ``{"driver": "node", "node": "sn1"}`` is captured by every studio service
    (live view, captures, recordings) like a local one. It uses the studio's open :class:`NodeNetwork` (the
    last one opened in this process), or its own when ``listen``/``connect`` endpoints are given.
    """

    driver = "node"

    def __init__(self, node: str, timeout_s: float = 10.0, listen: list[str] | None = None,
                 connect: list[str] | None = None):
        """Args:
        node: the node agent's name (``--name``).
        timeout_s: how long a read waits for the node's frame, and :meth:`open` for the node to appear (s).
        listen, connect: endpoints of a network of this device's own (default: the studio's open one).
        """
        self.node, self.timeout_s = str(node), float(timeout_s)
        self.listen, self.connect = listen, connect
        self._network: NodeNetwork | None = None
        self._own: NodeNetwork | None = None

    def open(self) -> None:
        """Find the network and wait (up to ``timeout_s``) for the node to be present."""
        if self.listen is not None or self.connect is not None:
            self._own = NodeNetwork(self.listen if self.listen is not None else [], self.connect)
            try:
                self._own.open()
            except InputError as exc:
                raise DeviceError(exc.message, self.describe()) from None
        self._network = self._own or open_network()
        if self._network is None:
            raise DeviceError("no node network is open in this studio (open one in the depth-network step, or "
                              "give this device listen or connect endpoints)", self.describe())
        deadline_s = time.monotonic() + self.timeout_s
        while not self._network.is_alive(self.node):
            if time.monotonic() > deadline_s:
                present = [s.name for s in self._network.nodes() if s.alive]
                self.close()
                raise DeviceError(f"node {self.node} did not appear within {self.timeout_s:g} s; nodes present: "
                                  f"{', '.join(present) or 'none'}", self.describe())
            time.sleep(QUERY_POLL_S)

    def read(self) -> Sample:
        """A full frame of the node; :class:`DeviceDisconnected` once the node has left the network."""
        if self._network is None:
            raise DeviceError("read() before open()", self.describe())
        try:
            return self._network.capture(self.node, self.timeout_s)
        except InputError as exc:
            if not self._network.is_alive(self.node):
                raise DeviceDisconnected(exc.message, self.describe()) from None
            raise DeviceError(exc.message, self.describe()) from None

    def close(self) -> None:
        if self._own is not None:
            self._own.close()
        self._network = self._own = None

    def describe(self) -> str:
        return f"node {self.node}"


_OPEN: list[NodeNetwork] = []
"""The networks open in this process, oldest first (:func:`open_network` gives the last)."""


def open_network() -> NodeNetwork | None:
    """The node network this process opened last and still holds open (the studio's: the demo's, or the one its
    depth-network step listens on), which the API's live captures and :class:`NetworkNode` use; None without one."""
    return _OPEN[-1] if _OPEN else None


FRAME_SLACK_BYTES = 1_000_000
"""Room above the frame limit that Zenoh still takes in, so the studio itself names a frame over it."""


def _oversized(node: str, n_bytes: int) -> str | None:
    """Why a frame of ``n_bytes`` from ``node`` is refused (over :data:`MAX_NODE_FRAME_MB`), else None."""
    if n_bytes <= MAX_NODE_FRAME_MB.value() * 1_000_000:
        return None
    return f"node {node} sent a {n_bytes:,}-byte frame: over {MAX_NODE_FRAME_MB.describe()}; nothing of it is kept"


def _identity(info: dict[str, Any]) -> tuple[str | None, str | None]:
    """What a node is, from its info reply: (device spec, the opened sensor's description with its serial)."""
    return info.get("device"), info.get("sensor")


def _identity_text(identity: tuple[str | None, str | None]) -> str:
    device, sensor = identity
    return f"{device or 'an unknown device'} ({sensor or 'unknown sensor'})"


def _trim(window: collections.deque, now: float) -> None:
    """Drop the window's entries older than :data:`WINDOW_S`."""
    while window and window[0][0] < now - WINDOW_S:
        window.popleft()
