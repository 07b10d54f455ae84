"""The Livox SDK 1 wire format (Horizon, Avia, Tele-15, Mid-40/70): point and IMU data packets, and control frames.

Everything is little-endian and packed, as ``sdk_core/include/livox_def.h`` and ``sdk_core/src/comm/sdk_protocol.cpp``
of Livox-SDK define it. Both the live driver (:mod:`backend.devices.livox`), the ``.lvx`` reader and the simulator
(:mod:`backend.sim.livox_sim`) use this module; it holds no sockets and no state.

**Data packets** (``LivoxEthPacket``, one UDP datagram each, on the host's data port): an 18-byte header
(:data:`ETH_HEADER`: protocol version, slot, LiDAR id, reserved, status code (uint32), time stamp type, data type,
time stamp (8 bytes)) and a fixed number of records of its data type:

=========  ==========================================  =========  ===============================================
data type  record                                      a packet   decoded as
=========  ==========================================  =========  ===============================================
2          ``LivoxExtendRawPoint``: int32 x, y, z       96         points (m), reflectivity, tag
           (mm), uint8 reflectivity, tag
4          ``LivoxDualExtendRawPoint``: two of those    48         both returns of a firing, at the firing's time
6          ``LivoxImuPoint``: float32 gyro x, y, z      1          gyro (rad/s), accel (m/s²: Livox sends g, which
           (rad/s), accel x, y, z (g)                              :data:`STANDARD_GRAVITY_M_S2` converts)
=========  ==========================================  =========  ===============================================

The protocol version of every SDK 1 data packet is :data:`SDK1_PROTOCOL_VERSION` (5); SDK 2 (Mid-360, HAP) is a
different protocol and is not read. The other data types (0, 1, 3, 5: the Mid-40's raw and spherical formats;
7, 8: triple return) are refused by :func:`check_data_header`, naming the type.

Points are in the LiDAR's frame: x forward, y left, z up, converted from int32 millimetres to float64 metres. A point
at the origin is Livox's "no return" and is dropped (its firing index is kept with the others, see
:class:`PointRecords`).

**Times.** The packet's time stamp is its first firing's time: nanoseconds for no sync, PTP and PPS (time stamp types
0, 1, 4), or for PPS+GPS (type 3) the UTC year (from 2000), month, day and hour in its first 4 bytes and the
microseconds into that hour in its last 4 (:func:`packet_times_ns`). Firing ``i`` of a packet is ``i`` point
intervals later (:data:`POINT_INTERVAL_NS` by device type: 4167 ns, i.e. 240,000 firings/s, for the Horizon, Tele-15
and Avia; 10 µs for the Mid-40 and Mid-70), as livox_ros_driver times its CustomMsg points; both returns of a
dual-return firing share its time.

**Control frames** (UDP, host command port <-> LiDAR port 65000): sof 0xAA, version 1, length (uint16, the whole
frame), command type (0 request, 1 acknowledgement, 2 message), sequence number (uint16), CRC-16 of those 7 bytes
(MCRF4XX: reflected polynomial 0x8408, seed 0x4C49, no final xor), command set, command id, payload, CRC-32 of
everything before it (the zlib CRC-32 with seed 0x564F580A). :func:`pack_frame` builds one, :func:`parse_frame`
checks and reads one. The commands the driver and simulator use are named below (``CMD_*``).
"""

from __future__ import annotations

import datetime as dt
import struct
import zlib
from dataclasses import dataclass

import numpy as np

# --------------------------------------------------------------------------------------------
# Data packets

SDK1_PROTOCOL_VERSION = 5
"""The version byte of every Livox SDK 1 data packet (``LivoxEthPacket.version``)."""
STANDARD_GRAVITY_M_S2 = 9.80665
"""Livox IMUs report acceleration in g; this converts it to m/s²."""

ETH_HEADER = np.dtype([("version", "u1"), ("slot", "u1"), ("lidar_id", "u1"), ("reserved", "u1"),
                       ("status", "<u4"), ("timestamp_type", "u1"), ("data_type", "u1"), ("timestamp", "<u8")])
"""The 18-byte header of a data packet (``LivoxEthPacket`` up to ``data``)."""
EXTEND_CARTESIAN = np.dtype([("x", "<i4"), ("y", "<i4"), ("z", "<i4"), ("reflectivity", "u1"), ("tag", "u1")])
"""``LivoxExtendRawPoint`` (data type 2): x, y, z in mm."""
DUAL_EXTEND_CARTESIAN = np.dtype([("returns", EXTEND_CARTESIAN, (2,))])
"""``LivoxDualExtendRawPoint`` (data type 4): the first and second return of one firing."""
IMU_POINT = np.dtype([("gyro", "<f4", (3,)), ("accel", "<f4", (3,))])
"""``LivoxImuPoint`` (data type 6): gyro in rad/s, accel in g."""

DATA_TYPE_EXTEND_CARTESIAN = 2
DATA_TYPE_DUAL_EXTEND_CARTESIAN = 4
DATA_TYPE_IMU = 6
DATA_TYPES: dict[int, tuple[np.dtype, int]] = {
    DATA_TYPE_EXTEND_CARTESIAN: (EXTEND_CARTESIAN, 96),
    DATA_TYPE_DUAL_EXTEND_CARTESIAN: (DUAL_EXTEND_CARTESIAN, 48),
    DATA_TYPE_IMU: (IMU_POINT, 1),
}
"""The data types read: their record and the records in a packet."""
DATA_TYPE_NAMES = {0: "Cartesian", 1: "spherical", 2: "extended Cartesian", 3: "extended spherical",
                   4: "dual extended Cartesian", 5: "dual extended spherical", 6: "IMU",
                   7: "triple extended Cartesian", 8: "triple extended spherical"}
"""``PointDataType`` of ``livox_def.h``."""
RETURNS_PER_FIRING = {DATA_TYPE_EXTEND_CARTESIAN: 1, DATA_TYPE_DUAL_EXTEND_CARTESIAN: 2}
TIMESTAMP_TYPES = {0: "no sync", 1: "PTP", 2: "reserved", 3: "PPS+GPS", 4: "PPS"}
"""``TimestampType`` of ``livox_def.h``."""
TIMESTAMP_PPS_GPS = 3

LIVOX_MODELS = {0: "Hub", 1: "Mid-40", 2: "Tele-15", 3: "Horizon", 6: "Mid-70", 7: "Avia"}
"""Livox SDK 1 device types (``DeviceType`` in ``livox_def.h``)."""
POINT_INTERVAL_NS = {0: 10_000, 1: 10_000, 2: 4_167, 3: 4_167, 4: 10_000, 5: 10_000, 6: 10_000, 7: 4_167, 8: 4_167}
"""Time between successive firings (ns) by device type, livox_ros_driver's ``product_type_info_pair_table``."""


def packet_size(data_type: int) -> int:
    """Bytes of a data packet of ``data_type`` (one of :data:`DATA_TYPES`): 1362 for types 2 and 4, 42 for 6."""
    record, count = DATA_TYPES[data_type]
    return ETH_HEADER.itemsize + record.itemsize * count


def check_data_header(version: int, data_type: int) -> None:
    """:class:`ValueError` saying what is wrong for a packet that is not SDK 1 or of a data type not read (the
    caller names the source)."""
    if version != SDK1_PROTOCOL_VERSION:
        raise ValueError(f"a data packet has protocol version {version}; expected {SDK1_PROTOCOL_VERSION} "
                         "(Livox SDK 1: Horizon, Avia, Tele-15, Mid-40/70; SDK 2 sensors such as the Mid-360 and HAP "
                         "are not supported)")
    if data_type not in DATA_TYPES:
        name = DATA_TYPE_NAMES.get(data_type, "unknown")
        raise ValueError(f"a data packet has data type {data_type} ({name}), which is not read; expected 2 (extended "
                         "Cartesian), 4 (dual extended Cartesian) or 6 (IMU)")


def data_headers(packets: np.ndarray) -> np.ndarray:
    """(P,) :data:`ETH_HEADER` records of (P, size) uint8 data packets (each row one packet)."""
    packets = np.ascontiguousarray(packets, np.uint8)
    return packets[:, :ETH_HEADER.itemsize].copy().view(ETH_HEADER).ravel()


def packet_times_ns(headers: np.ndarray) -> np.ndarray:
    """(P,) int64 time stamp (ns) of each packet header; PPS+GPS stamps converted from their UTC hour and
    microseconds to ns since the epoch. :class:`ValueError` for a PPS+GPS stamp that holds no date."""
    stamps = headers["timestamp"].astype(np.int64)
    for i in np.flatnonzero(headers["timestamp_type"] == TIMESTAMP_PPS_GPS):
        raw = int(headers["timestamp"][i])
        year, month, day, hour = (raw & 0xFF) + 2000, (raw >> 8) & 0xFF, (raw >> 16) & 0xFF, (raw >> 24) & 0xFF
        try:
            hour_start = dt.datetime(year, month, day, hour, tzinfo=dt.UTC)
        except ValueError:
            raise ValueError(f"a PPS+GPS time stamp holds no date ({year}-{month}-{day} {hour} h)") from None
        stamps[i] = round(hour_start.timestamp()) * 10**9 + (raw >> 32) * 1000
    return stamps


@dataclass
class PointRecords:
    """The returns of a batch of data packets of one data type (2 or 4); row ``i`` of every array is one return,
    returns at the origin (no return) left out."""

    points_m: np.ndarray
    """(N, 3) float64 points (m) in the LiDAR's frame."""
    reflectivity: np.ndarray
    """(N,) float32, 0-255."""
    tag: np.ndarray
    """(N,) uint8 Livox tag (noise confidence of the return, see the SDK's "Tag Information")."""
    packet: np.ndarray
    """(N,) int64 row of the packet (in the batch) each return came in."""
    firing: np.ndarray
    """(N,) int64 index of its firing within the packet (0..95 for type 2, 0..47 for type 4)."""
    return_index: np.ndarray
    """(N,) uint8: 0 for a single or first return, 1 for the second return of a dual-return firing."""
    offset_ns: np.ndarray
    """(N,) int64 time of its firing after its packet's time stamp (ns): ``firing`` point intervals."""


def decode_points(bodies: np.ndarray, data_type: int, interval_ns: int) -> PointRecords:
    """Decode the records of (P, 1344) uint8 packet bodies (the bytes after the 18-byte header) of ``data_type``
    2 or 4; ``interval_ns`` is the device type's :data:`POINT_INTERVAL_NS`."""
    record, count = DATA_TYPES[data_type]
    bodies = np.ascontiguousarray(bodies, np.uint8)
    flat = bodies.view(record).reshape(len(bodies), count)
    raw = flat["returns"] if data_type == DATA_TYPE_DUAL_EXTEND_CARTESIAN else flat[:, :, None]  # (P, count, returns)
    shape = raw.shape
    raw = raw.ravel()
    points_m = np.column_stack([raw["x"], raw["y"], raw["z"]]).astype(np.float64) * 1e-3
    keep = points_m.any(axis=1)
    packet, firing, return_index = (a.ravel()[keep] for a in np.indices(shape))
    return PointRecords(points_m=points_m[keep], reflectivity=raw["reflectivity"][keep].astype(np.float32),
                        tag=raw["tag"][keep], packet=packet.astype(np.int64), firing=firing.astype(np.int64),
                        return_index=return_index.astype(np.uint8),
                        offset_ns=firing.astype(np.int64) * int(interval_ns))


def decode_imu(bodies: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(gyro_rad_s, accel_m_s2)``, each (P, 3) float64, of (P, 24) uint8 IMU packet bodies (data type 6)."""
    imu = np.ascontiguousarray(bodies, np.uint8).view(IMU_POINT).ravel()
    return imu["gyro"].astype(np.float64), imu["accel"].astype(np.float64) * STANDARD_GRAVITY_M_S2


# --------------------------------------------------------------------------------------------
# Control frames

FRAME_SOF = 0xAA
FRAME_VERSION = 1
"""The version byte of a control frame (``kSdkVer0`` = 1 in ``sdk_protocol.cpp``)."""
FRAME_OVERHEAD = 15
"""Bytes of a frame around its payload: 9 of preamble, command set and id, 4 of CRC-32."""
MAX_FRAME_BYTES = 1400
"""Largest control frame taken (the SDK's command buffer holds 1536 bytes)."""
CMD_TYPE_REQUEST, CMD_TYPE_ACK, CMD_TYPE_MESSAGE = 0, 1, 2
CRC16_SEED = 0x4C49
CRC32_SEED = 0x564F580A

CMD_SET_GENERAL = 0
CMD_BROADCAST = 0
"""Message: broadcast code (16 bytes, NUL-padded), device type (uint8), reserved (uint16)."""
CMD_HANDSHAKE = 1
"""Request: host IP (4 bytes), data port, command port, IMU port (uint16). Ack: return code."""
CMD_HEARTBEAT = 3
"""Request: empty, at least once a second. Ack: return code, work state, feature, status code (uint32)."""
CMD_SAMPLING = 4
"""Request: 1 start, 0 stop. Ack: return code."""
CMD_DISCONNECT = 6
"""Request: empty. Ack: return code."""
DISCOVERY_PORT = 55000
"""UDP port the host listens on for broadcasts."""
LIDAR_COMMAND_PORT = 65000
"""UDP port a LiDAR takes commands on (and broadcasts from)."""
BROADCAST = struct.Struct("<16sBH")
HANDSHAKE = struct.Struct("<4sHHH")
HEARTBEAT_ACK = struct.Struct("<BBBI")


def _crc16_table() -> np.ndarray:
    table = np.arange(256, dtype=np.uint32)
    for _ in range(8):
        table = np.where(table & 1, (table >> 1) ^ 0x8408, table >> 1)
    return table.astype(np.uint16)


_CRC16_TABLE = _crc16_table().tolist()


def crc16(data: bytes) -> int:
    """The preamble CRC: CRC-16/MCRF4XX (reflected polynomial 0x8408, no final xor) seeded with 0x4C49."""
    crc = CRC16_SEED
    for byte in data:
        crc = (crc >> 8) ^ _CRC16_TABLE[(crc ^ byte) & 0xFF]
    return crc


def crc32(data: bytes) -> int:
    """The frame CRC: the standard CRC-32 seeded with 0x564F580A (the SDK's FastCRC32 equals zlib's)."""
    return zlib.crc32(data, CRC32_SEED)


@dataclass(frozen=True)
class Frame:
    """One control frame."""

    cmd_type: int
    """:data:`CMD_TYPE_REQUEST`, :data:`CMD_TYPE_ACK` or :data:`CMD_TYPE_MESSAGE`."""
    seq: int
    cmd_set: int
    cmd_id: int
    payload: bytes


def pack_frame(frame: Frame) -> bytes:
    """The bytes of ``frame``, CRCs included."""
    length = len(frame.payload) + FRAME_OVERHEAD
    preamble = struct.pack("<BBHBH", FRAME_SOF, FRAME_VERSION, length, frame.cmd_type, frame.seq & 0xFFFF)
    body = preamble + struct.pack("<H", crc16(preamble)) + bytes((frame.cmd_set, frame.cmd_id)) + frame.payload
    return body + struct.pack("<I", crc32(body))


def parse_frame(data: bytes) -> Frame:
    """The frame in ``data`` (one datagram); :class:`ValueError` saying what is wrong: too short or long, not a
    frame (sof), an unknown frame version, a length that disagrees with the datagram, a failed CRC."""
    if len(data) < FRAME_OVERHEAD or len(data) > MAX_FRAME_BYTES:
        raise ValueError(f"a control frame of {len(data)} bytes; expected {FRAME_OVERHEAD} to {MAX_FRAME_BYTES}")
    sof, version, length, cmd_type, seq, crc = struct.unpack_from("<BBHBHH", data)
    if sof != FRAME_SOF:
        raise ValueError(f"a control frame starts with 0x{sof:02x}; expected 0xaa")
    if version != FRAME_VERSION:
        raise ValueError(f"a control frame has version {version}; expected {FRAME_VERSION} (Livox SDK 1)")
    if length != len(data):
        raise ValueError(f"a control frame says it has {length} bytes but {len(data)} arrived")
    if crc16(data[:7]) != crc:
        raise ValueError("a control frame fails its preamble CRC-16")
    if crc32(data[:-4]) != struct.unpack_from("<I", data, length - 4)[0]:
        raise ValueError("a control frame fails its CRC-32")
    return Frame(cmd_type, seq, data[9], data[10], bytes(data[11:-4]))
