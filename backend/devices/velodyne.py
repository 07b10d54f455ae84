"""Velodyne spinning LiDARs (VLP-16 first): live over UDP and replayed from pcap recordings.

Both drivers cut the packet stream into full 360 deg scans the same way and decode each scan
with velodyne-decoder (:class:`velodyne_decoder.ScanDecoder`), so a recording of a live stream
gives the same scans as the live stream did.

**Scans.** A scan starts with a packet and takes every following packet until the azimuth of a
packet's first block has advanced 360 deg or more from the scan's first packet; that packet
starts the next scan. Every scan thus covers at least a full turn (plus at most one packet,
~4.8 deg at 600 rpm), no shot is in two scans, and cutting depends on the sensor's azimuths
only, never on network timing. (velodyne-decoder's own ``StreamDecoder`` also cuts on wall-clock
gaps of the host stamps, which would split scans when the network delivers in bursts, and it
does not say which packets went into a scan; hence the batching here, then ``ScanDecoder``.)
A scan is emitted when the packet after it arrives; a recording's last scan is emitted only if
it completes the turn. A jump back in azimuth (sensor restart, reordered datagram) drops the
partial scan.

**Frame.** velodyne-decoder returns points in the ROS sensor frame, which is the project's
LiDAR frame: x forward (azimuth 0, the side opposite the cable), y left, z up, metres. The
azimuth grows clockwise seen from above, so a shot at azimuth 90 deg lands on -y. The decoder
applies the VLP-16's per-laser vertical offsets (11.2 mm for the -15 deg laser, ...), so points
are exact in the frame whose origin is the sensor's optical centre on the rotation axis. No
conversion is needed; the points are only cast to float64.

**Samples.** ``points`` (N, 3) float64 (m, sensor frame), ``intensity`` (N,) float32
calibrated reflectivity 0..255, shots without return left out. ``meta``: ``scan_index``,
``packets`` (in this scan), ``port`` (UDP) or ``source`` (pcap), ``model``, ``malformed``
(datagrams skipped so far: wrong size or not a data packet), ``complete`` (no gap of 1.5 packets
or more in azimuth or in the sensor's clock, i.e. no packet lost), ``sensor_time_s`` (the sensor's stamp of the
first packet, seconds past the hour).
"""

from __future__ import annotations

import errno
import re
import socket
import struct
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from backend.core.errors import InputError
from backend.devices.base import (
    CaptureDevice,
    DeviceDisconnected,
    DeviceError,
    Sample,
    register_driver,
    start_simulator,
)

PACKET_SIZE = 1206
"""UDP payload size of a Velodyne data packet (bytes)."""
_DUAL_RETURN = 0x39
_LAST_BLOCK_AZIMUTH = 11 * 100 + 2
_FULL_TURN = 36000  # azimuth units (0.01 deg) in a turn
_HOUR_US = 3_600_000_000  # the sensor's clock counts microseconds past the hour
_RECV_BUFFER_BYTES = 8 * 1024 * 1024

_PRODUCT_IDS = {"VLP16": 0x22, "PuckLite": 0x22, "PuckHiRes": 0x24, "HDL32E": 0x21, "VLP32C": 0x28,
                "VLS128": 0xA1, "AlphaPrime": 0xA1}
"""Factory byte 2 of each model's data packets (models absent here are not checked)."""
_PRODUCT_NAMES = {0x21: "HDL-32E", 0x22: "VLP-16", 0x24: "VLP-16 Hi-Res", 0x28: "VLP-32C", 0x31: "Velarray",
                  0xA1: "VLS-128"}


def _resolve_model(model: str, device: str) -> Any:
    """The velodyne_decoder ``Model`` named ``model`` (spelling-tolerant: ``VLP-16``, ``vlp16``)."""
    import velodyne_decoder as vd

    def key(name: str) -> str:
        return re.sub(r"[^a-z0-9]", "", name.lower())

    models = {key(name): member for name, member in vd.Model.__members__.items() if not name.startswith("HDL64")}
    found = models.get(key(str(model)))
    if found is None:
        raise DeviceError(
            f"unknown Velodyne model {model!r}; supported: VLP-16, Puck LITE, Puck Hi-Res, HDL-32E, VLP-32A, "
            "VLP-32B, VLP-32C, VLS-128 (the HDL-64E needs a calibration file and is not supported here)",
            device,
        )
    return found


def _block_azimuth(data: bytes, offset: int) -> int:
    return data[offset] | (data[offset + 1] << 8)


@dataclass
class _Scan:
    packets: list[tuple[float, bytes]]
    complete: bool


class _ScanAssembler:
    """Cuts a stream of data packets into full turns (see the module docstring)."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._packets: list[tuple[float, bytes]] = []
        self._coverage = 0
        self._prev_az = 0
        self._prev_us = 0
        self._max_step = 0
        self._packet_step = 0.0
        self._dt_range = [_HOUR_US, 0]  # min, max sensor-time step between packets (us)

    def push(self, data: bytes, stamp: float) -> _Scan | None:
        """Add one valid data packet; return the scan it completes, if any."""
        az = _block_azimuth(data, 2)
        sensor_us = int.from_bytes(data[PACKET_SIZE - 6:PACKET_SIZE - 2], "little")
        done = None
        if self._packets:
            step = (az - self._prev_az) % _FULL_TURN
            if step > _FULL_TURN // 2:  # azimuth went backwards: restart, reordering or a foreign stream
                self.reset()
            else:
                self._coverage += step
                self._max_step = max(self._max_step, step)
                dt = (sensor_us - self._prev_us) % _HOUR_US
                self._dt_range = [min(self._dt_range[0], dt), max(self._dt_range[1], dt)]
                if self._coverage >= _FULL_TURN:
                    done = self._take()
        self._packets.append((stamp, data))
        self._prev_az = az
        self._prev_us = sensor_us
        span = (_block_azimuth(data, _LAST_BLOCK_AZIMUTH) - az) % _FULL_TURN
        # azimuth step to the next packet: 12 blocks of one step each, or in dual-return mode
        # 6 pairs of blocks sharing an azimuth
        self._packet_step = span * (6 / 5 if data[PACKET_SIZE - 2] == _DUAL_RETURN else 12 / 11)
        return done

    def finish(self) -> _Scan | None:
        """At the end of a recording: the pending scan if it completes the turn, else None."""
        if not self._packets:
            return None
        # the turn is complete if the next packet would have started the next scan
        if self._coverage + self._packet_step >= _FULL_TURN - self._packet_step / 24:
            return self._take()
        self.reset()
        return None

    def _take(self) -> _Scan:
        # An azimuth step of 1.5 packets or more means packets were lost; so does a step in the
        # sensor's clock of 1.5 packet periods (this also catches losing a whole turn, which the
        # azimuth cannot see).
        complete = (self._max_step < 1.5 * max(self._packet_step, 1)
                    and self._dt_range[1] < 1.5 * self._dt_range[0] + 2)
        scan = _Scan(self._packets, complete=complete)
        self.reset()
        return scan


class _VelodyneBase(CaptureDevice):
    """What both drivers share: model check, batching, decoding, building samples."""

    model: str

    def _setup_decoder(self) -> None:
        import velodyne_decoder as vd

        member = _resolve_model(self.model, self.describe())
        self._expected_product = _PRODUCT_IDS.get(member.name)
        self._decoder = vd.ScanDecoder(vd.Config(model=member))
        self._vd = vd
        self._assembler = _ScanAssembler()
        self._scan_index = 0
        self.malformed_packets = 0

    def _is_data_packet(self, data: bytes | memoryview, n: int) -> bool:
        """True for a well-formed data packet; counts and rejects anything else."""
        if n != PACKET_SIZE or data[0] != 0xFF or data[1] != 0xEE:
            self.malformed_packets += 1
            return False
        product = data[PACKET_SIZE - 1]
        if self._expected_product is not None and product in _PRODUCT_NAMES and product != self._expected_product:
            raise DeviceError(
                f"the data packets come from a {_PRODUCT_NAMES[product]} (product id 0x{product:02x}) but the "
                f"sensor is set up as {self.model}; fix the model setting",
                self.describe(),
            )
        return True

    def _decode(self, scan: _Scan, timestamp_s: float, meta: dict[str, Any]) -> Sample:
        vector = self._vd.PacketVector()
        for stamp, data in scan.packets:
            vector.append(self._vd.VelodynePacket(stamp, data))
        _, cloud = self._decoder.decode(vector)
        cloud = np.asarray(cloud)
        first = scan.packets[0][1]
        sensor_us = struct.unpack_from("<I", first, PACKET_SIZE - 6)[0]
        meta = {
            "scan_index": self._scan_index,
            "packets": len(scan.packets),
            **meta,
            "model": self.model,
            "malformed": self.malformed_packets,
            "complete": scan.complete,
            "sensor_time_s": sensor_us * 1e-6,
        }
        self._scan_index += 1
        return Sample(
            timestamp_s=timestamp_s,
            points=cloud[:, :3].astype(np.float64),
            intensity=cloud[:, 3].astype(np.float32),
            meta=meta,
        )


@register_driver
class VelodyneUdp(_VelodyneBase):
    """A live Velodyne sending data packets over UDP; :meth:`read` returns the next full scan.

    ``timestamp_s`` of a sample is the host's clock (seconds since the epoch) when the scan's
    last packet arrived; ``meta["sender"]`` is the sensor's ``ip:port``.

    ``host="sim"`` binds 127.0.0.1 on a free port (``port`` is not used) and starts the simulated
    endpoint registered as ``"velodyne"`` (:func:`~backend.devices.base.start_simulator`) sending to
    it: a VLP-16 at the demo rig's ground-truth pose of ``sim_sensor`` scanning the shared simulated
    yard at the real packet rate (~10 scans/s), so the simulated sensor can be picked like any other device.
    :attr:`simulator` is that sender (``simulator.unplug()`` pulls its cable); :meth:`close`
    stops it.
    """

    driver = "velodyne"

    def __init__(self, host: str = "127.0.0.1", port: int = 2368, model: str = "VLP-16", timeout_s: float = 2.0,
                 sim_sensor: str = "lidar_top"):
        """Settings as stored in the rig.

        Args:
            host: local address to bind; ``"0.0.0.0"`` listens on every interface (the sensor
                sends to 255.255.255.255 or to the host IP set in its web page); ``"sim"`` for
                the built-in simulator.
            port: UDP port of the data packets (2368 by factory default); 0 picks a free port
                (see :attr:`bound_port`), which simulators and tests use.
            model: sensor model, e.g. ``"VLP-16"``, ``"VLP-32C"``, ``"HDL-32E"``.
            timeout_s: how long without a data packet before :meth:`read` raises
                :class:`DeviceDisconnected` (s).
            sim_sensor: with ``host="sim"``, the ``lidar3d`` sensor of the demo rig whose
                ground-truth mounting poses the simulated VLP-16 (e.g. ``"lidar_top"``, ``"lidar_front"``).
        """
        self.host = host
        self.port = int(port)
        self.model = model
        self.timeout_s = float(timeout_s)
        self.sim_sensor = sim_sensor
        self.bound_port: int | None = None
        """The UDP port actually bound (differs from ``port`` when that is 0 or the host is ``"sim"``)."""
        self.simulator: Any = None
        """With ``host="sim"``, the simulated sensor sending to :attr:`bound_port` while open (``stop()``,
        ``unplug()``, ``replug()``, ``packets_sent``, ``garbage_every``)."""
        self._sock: socket.socket | None = None
        self._buf = bytearray(65536)

    def describe(self) -> str:
        if self.host == "sim":
            return f"velodyne {self.model} sim {self.sim_sensor} udp 127.0.0.1:{self.bound_port or 0}"
        return f"velodyne {self.model} udp {self.host}:{self.bound_port or self.port}"

    def open(self) -> None:
        """Bind the UDP socket (and start the simulator for ``host="sim"``); :class:`DeviceError` if
        the address is taken or not local, or ``sim_sensor`` is not a 3D LiDAR of the demo rig."""
        if self.timeout_s <= 0:
            raise DeviceError(f"timeout_s must be positive, not {self.timeout_s}", self.describe())
        self.close()
        simulated = self.host == "sim"
        device = self.describe()  # errors of the simulator name the device as it was asked for
        host, port = ("127.0.0.1", 0) if simulated else (self.host, self.port)
        self._setup_decoder()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _RECV_BUFFER_BYTES)
            sock.bind((host, port))
        except OSError as exc:
            sock.close()
            hint = (" — another program (a ROS velodyne driver, VeloView, a second studio) holds it"
                    if exc.errno == errno.EADDRINUSE else " — is this address one of this machine's interfaces?")
            raise DeviceError(f"cannot bind udp {host}:{port}: {exc.strerror or exc}{hint}",
                              self.describe()) from None
        self._sock = sock
        self.bound_port = sock.getsockname()[1]
        if simulated:
            try:
                self.simulator = start_simulator("velodyne", device, port=self.bound_port, sensor=self.sim_sensor)
            except BaseException:
                self.close()
                raise

    def read(self) -> Sample:
        """Block until a full scan has arrived; :class:`DeviceDisconnected` after ``timeout_s`` of silence."""
        sock = self._sock
        if sock is None:
            raise DeviceError("not open; call open() first", self.describe())
        buf = self._buf
        view = memoryview(buf)
        deadline = time.monotonic() + self.timeout_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self._assembler.reset()  # a scan interrupted by silence is not a full turn
                extra = f"; {self.malformed_packets} malformed datagrams were ignored" if self.malformed_packets else ""
                raise DeviceDisconnected(
                    f"no Velodyne packets on udp port {self.bound_port} for {self.timeout_s:g} s — check the "
                    f"sensor's IP/port and that nothing else is bound{extra}",
                    self.describe(),
                )
            sock.settimeout(remaining)
            try:
                n, sender = sock.recvfrom_into(buf)
            except TimeoutError:
                continue
            except OSError as exc:
                raise DeviceDisconnected(f"udp socket failed: {exc}", self.describe()) from None
            if not self._is_data_packet(view, n):
                continue
            deadline = time.monotonic() + self.timeout_s
            now = time.time()
            scan = self._assembler.push(bytes(view[:n]), now)
            if scan is not None:
                return self._decode(scan, scan.packets[-1][0],
                                    {"port": self.bound_port, "sender": f"{sender[0]}:{sender[1]}"})

    def close(self) -> None:
        """Stop the simulator (``host="sim"``) and release the socket. Safe twice."""
        if self.simulator is not None:
            self.simulator.stop()
            self.simulator = None
        if self._sock is not None:
            self._sock.close()
            self._sock = None


# --- pcap -------------------------------------------------------------------------------------------------------------
# Classic libpcap files (the format tcpdump and Wireshark's "pcap" write), parsed with struct:
# a 24-byte global header, then records of a 16-byte header and the captured frame.

_PCAP_MAGICS = {b"\xd4\xc3\xb2\xa1": ("<", 1e-6), b"\xa1\xb2\xc3\xd4": (">", 1e-6),
                b"\x4d\x3c\xb2\xa1": ("<", 1e-9), b"\xa1\xb2\x3c\x4d": (">", 1e-9)}
_LINK_ETHERNET, _LINK_NULL, _LINK_RAW, _LINK_RAW_IPV4, _LINK_SLL, _LINK_SLL2 = 1, 0, 101, 228, 113, 276
_SUPPORTED_LINKS = {_LINK_ETHERNET, _LINK_NULL, _LINK_RAW, 12, 14, _LINK_RAW_IPV4, _LINK_SLL, _LINK_SLL2}


class _PcapFile:
    """Reads UDP/IPv4 payloads from a classic pcap; every problem is an :class:`InputError` naming the file."""

    def __init__(self, path: Path):
        self.path = path
        name = path.name
        try:
            size = path.stat().st_size
            f: BinaryIO = path.open("rb")
        except OSError as exc:
            raise InputError(f"{name}: cannot read the pcap file ({exc.strerror or exc})", input=str(path)) from None
        self._f = f
        header = f.read(24)
        if header[:4] == b"\x0a\x0d\x0d\x0a":
            self.close()
            raise InputError(f"{name} is a pcapng file; save it as classic pcap (editcap -F pcap {name} out.pcap)",
                             input=str(path))
        if len(header) < 24 or header[:4] not in _PCAP_MAGICS:
            self.close()
            what = "is empty" if not header else "is not a pcap file (no pcap magic number)"
            raise InputError(f"{name} {what}; expected a tcpdump/Wireshark .pcap recording", input=str(path))
        self._endian, self._tick = _PCAP_MAGICS[header[:4]]
        self.link = struct.unpack(self._endian + "I", header[20:24])[0] & 0x0FFFFFFF
        if self.link not in _SUPPORTED_LINKS:
            self.close()
            raise InputError(f"{name}: unsupported pcap link type {self.link} (expected Ethernet, raw IP or "
                             "Linux cooked capture)", input=str(path))
        # Walk the record headers once so that a cut-off file is reported at open, not mid-replay.
        offset, records, record = 24, 0, struct.Struct(self._endian + "IIII")
        while offset < size:
            f.seek(offset)
            head = f.read(16)
            if len(head) < 16:
                self._truncated(offset, records, f"a record header needs 16 bytes, {len(head)} remain")
            incl_len = record.unpack(head)[2]
            if incl_len > 0x4000000:
                self._truncated(offset, records, f"record claims {incl_len} bytes; the file is corrupt")
            if offset + 16 + incl_len > size:
                self._truncated(offset, records, f"the record needs {incl_len} bytes, {size - offset - 16} remain")
            offset += 16 + incl_len
            records += 1
        self.records = records
        f.seek(24)

    def _truncated(self, offset: int, records: int, detail: str) -> None:
        self.close()
        raise InputError(
            f"{self.path.name} is truncated at byte {offset} after {records} complete packets ({detail}); "
            "was the capture cut off? `tcpdump -r` can rewrite its complete packets",
            input=str(self.path),
        )

    def udp_payloads(self) -> Iterator[tuple[float, int, bytes]]:
        """``(time_s, dst_port, payload)`` of each UDP/IPv4 datagram, in file order."""
        record = struct.Struct(self._endian + "IIII")
        f = self._f
        while True:
            head = f.read(16)
            if len(head) < 16:
                return
            sec, frac, incl_len, _ = record.unpack(head)
            frame = f.read(incl_len)
            ip = self._ip_packet(frame)
            if ip is None or len(ip) < 20 or ip[0] >> 4 != 4 or ip[9] != 17:
                continue
            if struct.unpack_from("!H", ip, 6)[0] & 0x3FFF:  # a fragment: Velodyne never fragments
                continue
            ihl = (ip[0] & 0x0F) * 4
            if len(ip) < ihl + 8:
                continue
            dst_port, udp_len = struct.unpack_from("!HH", ip, ihl + 2)
            yield sec + frac * self._tick, dst_port, ip[ihl + 8:ihl + max(udp_len, 8)]

    def _ip_packet(self, frame: bytes) -> bytes | None:
        link = self.link
        if link == _LINK_ETHERNET:
            off, ethertype = 14, frame[12:14]
            while ethertype in (b"\x81\x00", b"\x88\xa8"):  # VLAN tags
                ethertype = frame[off + 2:off + 4]
                off += 4
            return frame[off:] if ethertype == b"\x08\x00" else None
        if link == _LINK_SLL:
            return frame[16:] if frame[14:16] == b"\x08\x00" else None
        if link == _LINK_SLL2:
            return frame[20:] if frame[0:2] == b"\x08\x00" else None
        if link == _LINK_NULL:
            return frame[4:]
        return frame  # raw IP

    def close(self) -> None:
        self._f.close()


@register_driver
class VelodynePcap(_VelodyneBase):
    """Scans replayed from a pcap recording of a Velodyne (tcpdump, Wireshark, VeloView).

    Samples come as fast as they are read; ``timestamp_s`` is the capture time (seconds since
    the epoch) of the scan's last packet and ``meta["source"]`` the file name. At the end,
    :meth:`read` raises :class:`DeviceDisconnected`. A missing, non-pcap or truncated file
    raises :class:`~backend.core.errors.InputError` naming it, from :meth:`open`.
    """

    driver = "velodyne_pcap"

    def __init__(self, path: str, model: str = "VLP-16", port: int | None = None):
        """Settings as stored in the rig.

        Args:
            path: the ``.pcap`` file (classic libpcap; pcapng must be converted).
            model: sensor model, e.g. ``"VLP-16"``.
            port: UDP destination port of the data packets; None takes every 1206-byte UDP
                payload that is a data packet, whatever its port (2368 by factory default).
        """
        self.path = Path(path)
        self.model = model
        self.port = port
        self._pcap: _PcapFile | None = None
        self._payloads: Iterator[tuple[float, int, bytes]] | None = None
        self._ended = False

    def describe(self) -> str:
        return f"velodyne {self.model} pcap {self.path.name}"

    def open(self) -> None:
        """Check the file (header and every record's length) and set up the decoder."""
        self._setup_decoder()
        if self._pcap is not None:
            self._pcap.close()
        self._pcap = _PcapFile(self.path)
        self._payloads = self._pcap.udp_payloads()
        self._ended = False

    def read(self) -> Sample:
        """The next full scan; :class:`DeviceDisconnected` at the end of the recording."""
        if self._payloads is None:
            raise DeviceError("not open; call open() first", self.describe())
        meta = {"source": self.path.name}
        if not self._ended:
            for stamp, dst_port, payload in self._payloads:
                if self.port is not None and dst_port != self.port:
                    continue
                if len(payload) != PACKET_SIZE:
                    if self.port is not None:
                        self.malformed_packets += 1
                    continue  # other traffic (position packets, ...) when no port is set
                if not self._is_data_packet(payload, len(payload)):
                    continue
                scan = self._assembler.push(payload, stamp)
                if scan is not None:
                    return self._decode(scan, scan.packets[-1][0], meta)
            self._ended = True
            scan = self._assembler.finish()
            if scan is not None:
                return self._decode(scan, scan.packets[-1][0], meta)
        if self._scan_index == 0:
            where = f"to udp port {self.port}" if self.port is not None else "(1206-byte UDP payloads)"
            raise InputError(f"{self.path.name} holds no full turn of Velodyne data packets {where}",
                             input=str(self.path))
        raise DeviceDisconnected(f"end of recording after {self._scan_index} scans", self.describe())

    def close(self) -> None:
        if self._pcap is not None:
            self._pcap.close()
            self._pcap = None
            self._payloads = None
