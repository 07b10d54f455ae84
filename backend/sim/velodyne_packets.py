"""Byte-level Velodyne VLP-16 simulator: genuine data packets of the shared simulated yard, pcap files.

A VLP-16 data packet is the 1206-byte payload of a UDP datagram sent to port 2368:

* 12 blocks of 100 bytes: flag ``0xFFEE`` (bytes ``FF EE``), azimuth (uint16 LE, 0.01 deg),
  then 32 channel records (distance uint16 LE in 2 mm units, 0 = no return;
  calibrated reflectivity uint8). A block holds **two firing sequences** of the 16 lasers
  (channels 0..15 then 0..15 again), so a packet carries 24 firing columns;
* a 4-byte timestamp (uint32 LE, microseconds past the hour, of the packet's first firing);
* 2 factory bytes: return mode (``0x37`` strongest, ``0x38`` last, ``0x39`` dual) and product
  id (``0x22`` VLP-16).

Timing (VLP-16 manual): a laser fires every 2.304 us, a firing sequence of 16 lasers takes
55.296 us, so a packet spans 1327.104 us and a 600 rpm sensor sends ~753.5 packets/s.

Only the first column of each block carries an azimuth; the azimuth of each laser shot is
interpolated as the manual prescribes::

    azimuth = block_azimuth + delta * (channel * 2.304 us + firing * 55.296 us) / 110.592 us

where ``delta`` is the azimuth step to the next block of the packet (the last block reuses the
previous step). The simulator fires each laser along exactly that azimuth, so a correct decoder
recovers the simulated points up to the range quantisation (2 mm steps) and its own rounding of
the azimuth to 0.01 deg.

Geometry, as velodyne-decoder (and VeloView, ROS) decodes it: the sensor frame is x forward
(azimuth 0), y left, z up; the azimuth grows clockwise seen from above, so a shot at azimuth
``a`` and elevation ``w`` points along ``(cos w cos a, -cos w sin a, sin w)``. Laser ``k``
starts at ``(0, 0, VLP16_VERTICAL_OFFSET_M[k])`` (the VLP-16 manual's vertical corrections),
and the distance is measured from there.

The scene is the shared yard of :class:`backend.sim.lidar_scene.LidarScene` (the one the
``simulated_lidar`` driver and the YDLiDAR simulator scan), seen from a ``T_base_lidar``
(default: the demo rig's ground-truth ``lidar_top`` mounting); each surface returns its
:data:`~backend.sim.lidar_scene.REFLECTIVITY` as calibrated reflectivity.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from backend.sim.demo_rig import demo_rig
from backend.sim.lidar_scene import LidarScene, label_reflectivity

PACKET_SIZE = 1206
"""Bytes of UDP payload of one VLP-16 data packet."""
BLOCKS_PER_PACKET = 12
CHANNELS = 16
COLUMNS_PER_PACKET = 2 * BLOCKS_PER_PACKET
"""Firing sequences (columns of 16 shots) per packet: two per block."""
CHANNEL_PERIOD_US = 2.304
"""Time between two lasers of one firing sequence (us)."""
FIRING_PERIOD_US = 55.296
"""Time between two firing sequences (us)."""
PACKET_PERIOD_US = COLUMNS_PER_PACKET * FIRING_PERIOD_US
"""Time spanned by one packet (us): 1327.104."""
DISTANCE_UNIT_M = 0.002
"""Range quantisation of the distance field (m)."""
MAX_ENCODED_RANGE_M = 0xFFFF * DISTANCE_UNIT_M
"""Longest range the 16-bit distance field holds (m)."""
DATA_PORT = 2368
"""UDP port of Velodyne data packets."""
RETURN_STRONGEST = 0x37
RETURN_LAST = 0x38
RETURN_DUAL = 0x39
PRODUCT_VLP16 = 0x22

VLP16_ELEVATION_DEG = np.array([-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15], dtype=float)
"""Elevation of laser (channel) 0..15 in firing order (deg)."""
VLP16_VERTICAL_OFFSET_M = -0.04191 * np.tan(np.radians(VLP16_ELEVATION_DEG))
"""Height of each laser's origin above the sensor frame's origin (m): the VLP-16 manual's
vertical corrections (11.2, -0.7, 9.7, ... mm), to the precision velodyne-decoder applies."""
VLP16_RING = np.argsort(np.argsort(VLP16_ELEVATION_DEG))
"""Ring of each channel: its rank by elevation (0 = lowest beam), as decoders report it."""

_BLOCK_DTYPE = np.dtype(
    [("flag", "<u2"), ("azimuth", "<u2"), ("measurements", [("distance", "<u2"), ("reflectivity", "u1")], 32)]
)
_PACKET_DTYPE = np.dtype(
    [("blocks", _BLOCK_DTYPE, BLOCKS_PER_PACKET), ("timestamp", "<u4"), ("return_mode", "u1"), ("product", "u1")]
)
assert _PACKET_DTYPE.itemsize == PACKET_SIZE
TIMESTAMP_OFFSET: int = _PACKET_DTYPE.fields["timestamp"][1]
"""Byte offset of a packet's timestamp (uint32 LE, microseconds past the hour): 1200."""
_HOUR_US = 3_600_000_000


def shot_directions(azimuth_deg: np.ndarray, channel: np.ndarray | None = None) -> np.ndarray:
    """Unit direction of shots at ``azimuth_deg`` (clockwise from x, deg), (..., 16) by channel.

    With ``channel`` given, it broadcasts against ``azimuth_deg`` instead of the last axis
    being the 16 channels. Returns (..., 3) in the sensor frame (x forward, y left, z up).
    """
    a = np.radians(np.asarray(azimuth_deg, dtype=float))
    ch = np.arange(CHANNELS) if channel is None else np.asarray(channel)
    w = np.radians(VLP16_ELEVATION_DEG[ch])
    return np.stack([np.cos(w) * np.cos(a), -np.cos(w) * np.sin(a), np.sin(w) + 0 * a], axis=-1)


def shot_origins(channel: np.ndarray | None = None) -> np.ndarray:
    """(16, 3) or (..., 3) origin of each laser in the sensor frame (m)."""
    ch = np.arange(CHANNELS) if channel is None else np.asarray(channel)
    z = VLP16_VERTICAL_OFFSET_M[ch]
    return np.stack([0 * z, 0 * z, z], axis=-1)


def interpolated_azimuths_deg(block_azimuth_cdeg: np.ndarray) -> np.ndarray:
    """Azimuth of every shot (deg, in [0, 360)) from the blocks' encoded azimuths.

    ``block_azimuth_cdeg`` is (n_packets, 12) in 0.01 deg. Returns (n_packets * 24, 16):
    one row per column (two per block), one entry per channel, as the VLP-16 manual
    interpolates them (the last block of a packet reuses the previous block's step).
    """
    az = np.asarray(block_azimuth_cdeg, dtype=float)
    step = np.mod(np.diff(az, axis=1), 36000.0)
    step = np.concatenate([step, step[:, -1:]], axis=1)  # (n_packets, 12)
    firing = np.arange(2)[:, None]
    channel = np.arange(CHANNELS)[None, :]
    frac = (channel * CHANNEL_PERIOD_US + firing * FIRING_PERIOD_US) / (2 * FIRING_PERIOD_US)  # (2, 16)
    shots = az[:, :, None, None] + step[:, :, None, None] * frac[None, None]  # (n_packets, 12, 2, 16)
    return np.mod(shots.reshape(-1, CHANNELS), 36000.0) / 100.0


def encode_vlp16_packets(
    ranges_m: np.ndarray,
    azimuths_deg: np.ndarray,
    reflectivity: np.ndarray | int = 100,
    timestamp_us: int | Sequence[int] = 0,
    *,
    return_mode: int = RETURN_STRONGEST,
    product_id: int = PRODUCT_VLP16,
) -> list[bytes]:
    """Build genuine VLP-16 data packets (1206 bytes each) from firing columns.

    Args:
        ranges_m: (n_columns, 16) distance of each shot (m) from its laser's origin, by channel
            (firing order, see :data:`VLP16_ELEVATION_DEG`); 0, NaN, inf or beyond 131 m mean
            no return. Columns are consecutive firing sequences, 24 per packet; a last partial
            packet is padded with columns without returns.
        azimuths_deg: (n_columns,) azimuth of each column's first shot (deg, clockwise from x
            forward). Only even columns' azimuths are sent (one per block); the odd columns'
            are implied by the interpolation described in this module's docstring.
        reflectivity: calibrated reflectivity 0..255, scalar or (n_columns, 16).
        timestamp_us: microseconds past the hour of the first packet (following packets are
            1327.104 us apart), or one value per packet; wrapped at the hour.
        return_mode: factory byte 1 (0x37 strongest, 0x38 last, 0x39 dual).
        product_id: factory byte 2 (0x22 for a VLP-16).

    Returns:
        One ``bytes`` of :data:`PACKET_SIZE` per packet.
    """
    ranges = np.asarray(ranges_m, dtype=float)
    if ranges.ndim != 2 or ranges.shape[1] != CHANNELS:
        raise ValueError(f"ranges_m must be (n_columns, 16), not {ranges.shape}")
    n_columns = ranges.shape[0]
    az = np.asarray(azimuths_deg, dtype=float).reshape(-1)
    if az.shape[0] != n_columns:
        raise ValueError(f"azimuths_deg has {az.shape[0]} entries for {n_columns} columns")
    refl = np.broadcast_to(np.asarray(reflectivity), ranges.shape)
    n_packets = -(-n_columns // COLUMNS_PER_PACKET)
    n_padded = n_packets * COLUMNS_PER_PACKET
    if n_padded > n_columns:  # pad with empty columns, continuing the rotation
        step = az[-1] - az[-2] if n_columns > 1 else 0.0
        az = np.concatenate([az, az[-1] + step * np.arange(1, n_padded - n_columns + 1)])
        ranges = np.concatenate([ranges, np.zeros((n_padded - n_columns, CHANNELS))])
        refl = np.concatenate([refl, np.zeros((n_padded - n_columns, CHANNELS), dtype=refl.dtype)])

    valid = np.isfinite(ranges) & (ranges > 0) & (ranges < MAX_ENCODED_RANGE_M)
    distance = np.where(valid, np.round(np.where(valid, ranges, 0) / DISTANCE_UNIT_M), 0).astype(np.uint16)
    refl = np.clip(np.where(valid, refl, 0), 0, 255).astype(np.uint8)

    stamps = np.asarray(timestamp_us, dtype=np.int64)
    if stamps.ndim == 0:
        stamps = int(stamps) + np.round(np.arange(n_packets) * PACKET_PERIOD_US).astype(np.int64)
    elif stamps.shape != (n_packets,):
        raise ValueError(f"timestamp_us needs one value per packet ({n_packets}), not {stamps.shape}")

    packets = np.zeros(n_packets, dtype=_PACKET_DTYPE)
    blocks = packets["blocks"]
    blocks["flag"] = 0xEEFF  # little-endian: bytes FF EE
    blocks["azimuth"] = np.mod(np.round(az[0::2] * 100.0), 36000).astype(np.uint16).reshape(n_packets, 12)
    # block b holds columns 2b (channels 0..15) and 2b+1 (channels 16..31)
    blocks["measurements"]["distance"] = distance.reshape(n_packets, BLOCKS_PER_PACKET, 32)
    blocks["measurements"]["reflectivity"] = refl.reshape(n_packets, BLOCKS_PER_PACKET, 32)
    packets["timestamp"] = np.mod(stamps, _HOUR_US).astype(np.uint32)
    packets["return_mode"] = return_mode
    packets["product"] = product_id
    raw = packets.tobytes()
    return [raw[i * PACKET_SIZE:(i + 1) * PACKET_SIZE] for i in range(n_packets)]


# --- the scene ------------------------------------------------------------------------------------------------------

RangesFn = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
"""``fn(origins (M, 3), unit directions (M, 3)) -> (ranges (M,), labels (M,))``, rays in the sensor
frame (m); ranges in metres (0, NaN or inf = no return), labels of
:data:`~backend.sim.lidar_scene.LABELS` (0 = nothing hit) that pick each return's reflectivity."""


def scene_ranges_fn(scene: LidarScene | None = None, T_base_lidar: np.ndarray | None = None) -> RangesFn:
    """A :data:`RangesFn` ray-casting ``scene`` (default a fresh :class:`LidarScene`) from a sensor at
    ``T_base_lidar`` (4x4, m, sensor frame into base_link; default the demo rig's ``lidar_top``)."""
    scene = LidarScene() if scene is None else scene
    T = demo_rig().T_root_frame("lidar_top") if T_base_lidar is None else np.asarray(T_base_lidar, dtype=float)

    def cast(origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ranges, labels, _ = scene.cast(origins @ T[:3, :3].T + T[:3, 3], directions @ T[:3, :3].T)
        return ranges, labels

    return cast


@dataclass
class Vlp16Sim:
    """Packets of a simulated VLP-16 and the ground truth behind them (sensor frame, m)."""

    packets: list[bytes]
    """The data packets (1206 bytes each), in sending order."""
    ranges_m: np.ndarray
    """(n_columns, 16) simulated range of each shot (m), 0 for no return (before quantisation)."""
    azimuths_deg: np.ndarray
    """(n_columns, 16) azimuth of each shot (deg, clockwise from x forward)."""
    points: np.ndarray
    """(n_columns, 16, 3) true hit point of each shot (m), NaN where there is no return."""
    reflectivity: np.ndarray
    """(n_columns, 16) uint8 reflectivity of each shot."""
    labels: np.ndarray
    """(n_columns, 16) label (:data:`~backend.sim.lidar_scene.LABELS`) of what each shot hit, 0 for no return."""
    rpm: float
    timestamp_us: int
    """Microseconds past the hour of the first packet."""

    @property
    def packets_per_rotation(self) -> float:
        return 60e6 / self.rpm / PACKET_PERIOD_US

    def truth(self, first_packet: int = 0, n_packets: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ground truth of packets ``[first_packet, first_packet + n_packets)``.

        Returns ``(points (N, 3), reflectivity (N,), ring (N,))`` of the shots with a return,
        column by column and channel by channel within a column (the order decoders emit).
        """
        stop = len(self.packets) if n_packets is None else first_packet + n_packets
        cols = slice(first_packet * COLUMNS_PER_PACKET, stop * COLUMNS_PER_PACKET)
        valid = self.ranges_m[cols] > 0
        ring = np.broadcast_to(VLP16_RING, valid.shape)
        return self.points[cols][valid], self.reflectivity[cols][valid], ring[valid]


def simulate_vlp16_scan(
    ranges_fn: RangesFn | None = None,
    *,
    rpm: float = 600.0,
    n_rotations: float = 1.0,
    start_azimuth_deg: float = 0.0,
    timestamp_us: int = 0,
    range_noise_m: float = 0.0,
    seed: int = 0,
) -> Vlp16Sim:
    """A deterministic spinning VLP-16 scanning a scene, as data packets with ground truth.

    Args:
        ranges_fn: the ray caster (default :func:`scene_ranges_fn`: the shared yard from the demo
            rig's ``lidar_top``); each return's reflectivity is its label's
            :func:`~backend.sim.lidar_scene.label_reflectivity`.
        rpm: rotation speed (300..1200 on a real VLP-16).
        n_rotations: how many turns to simulate; rounded up to whole packets.
        start_azimuth_deg: azimuth of the first shot (deg).
        timestamp_us: microseconds past the hour of the first packet.
        range_noise_m: 1-sigma Gaussian range noise (m) added before quantisation; the ground
            truth points carry the noise too (they are where the sensor says the shot ended).
        seed: seeds the noise.
    """
    if rpm <= 0:
        raise ValueError(f"rpm must be positive, not {rpm}")
    ranges_fn = scene_ranges_fn() if ranges_fn is None else ranges_fn
    deg_per_us = rpm * 360.0 / 60e6
    n_packets = int(np.ceil(n_rotations * 60e6 / rpm / PACKET_PERIOD_US - 1e-9))
    block_time_us = np.arange(n_packets * BLOCKS_PER_PACKET) * 2 * FIRING_PERIOD_US
    block_az_cdeg = np.mod(np.round((start_azimuth_deg + deg_per_us * block_time_us) * 100.0), 36000)
    azimuths = interpolated_azimuths_deg(block_az_cdeg.reshape(n_packets, BLOCKS_PER_PACKET))  # (C, 16)
    dirs = shot_directions(azimuths)  # (C, 16, 3)
    origins = np.broadcast_to(shot_origins(), dirs.shape)
    ranges, labels = ranges_fn(origins.reshape(-1, 3), dirs.reshape(-1, 3))
    ranges = np.asarray(ranges, dtype=float).reshape(azimuths.shape)
    hit = np.isfinite(ranges) & (ranges > 0) & (ranges < MAX_ENCODED_RANGE_M)
    ranges = np.where(hit, ranges, 0.0)
    labels = np.where(hit, np.asarray(labels).reshape(azimuths.shape), 0).astype(np.int8)
    refl = np.round(label_reflectivity(labels)).astype(np.uint8)
    if range_noise_m > 0:
        noise = np.random.default_rng(seed).normal(0.0, range_noise_m, ranges.shape)
        ranges = np.where(hit, np.maximum(ranges + noise, DISTANCE_UNIT_M), 0.0)
    points = np.where(hit[..., None], origins + ranges[..., None] * dirs, np.nan)
    packets = encode_vlp16_packets(ranges, azimuths[:, 0], refl, timestamp_us)
    return Vlp16Sim(packets=packets, ranges_m=ranges, azimuths_deg=azimuths, points=points, reflectivity=refl,
                    labels=labels, rpm=float(rpm), timestamp_us=int(timestamp_us))


# --- pcap -----------------------------------------------------------------------------------------------------------
# Classic libpcap format (not pcapng), written with struct: a 24-byte global header, then per
# packet a 16-byte record header and the frame. Frames are Ethernet II / IPv4 / UDP.

PCAP_MAGIC_US = 0xA1B2C3D4
LINKTYPE_ETHERNET = 1


def _ipv4_checksum(header: bytes) -> int:
    total = sum(struct.unpack(f"!{len(header) // 2}H", header))
    while total >> 16:
        total = (total & 0xFFFF) + (total >> 16)
    return ~total & 0xFFFF


def udp_frame(payload: bytes, dst_port: int = DATA_PORT, src_port: int = DATA_PORT, *,
              src_ip: str = "192.168.1.201", dst_ip: str = "255.255.255.255", ident: int = 0) -> bytes:
    """An Ethernet II / IPv4 / UDP frame carrying ``payload``, with correct lengths and IP checksum."""
    udp = struct.pack("!HHHH", src_port, dst_port, 8 + len(payload), 0) + payload  # UDP checksum 0: none (IPv4)
    src = bytes(int(x) for x in src_ip.split("."))
    dst = bytes(int(x) for x in dst_ip.split("."))
    ip = struct.pack("!BBHHHBBH4s4s", 0x45, 0, 20 + len(udp), ident & 0xFFFF, 0x4000, 64, 17, 0, src, dst)
    ip = ip[:10] + struct.pack("!H", _ipv4_checksum(ip)) + ip[12:]
    eth = b"\xff" * 6 + bytes.fromhex("607688000001") + struct.pack("!H", 0x0800)  # broadcast <- Velodyne OUI
    return eth + ip + udp


def write_pcap(
    path: str | Path,
    packets: Sequence[bytes | tuple[int, bytes]],
    port: int = DATA_PORT,
    *,
    start_time_s: float = 1_700_000_000.0,
    packet_period_s: float = PACKET_PERIOD_US * 1e-6,
    timestamps_s: Sequence[float] | None = None,
) -> Path:
    """Write UDP payloads as a classic pcap (Ethernet, microsecond stamps), as tcpdump would.

    Each item of ``packets`` is a payload sent to ``port``, or ``(dst_port, payload)`` to mix in
    other traffic (e.g. 512-byte position packets to port 8308). Record ``i`` is stamped
    ``timestamps_s[i]`` or ``start_time_s + i * packet_period_s`` (seconds since the epoch).
    """
    path = Path(path)
    with path.open("wb") as f:
        f.write(struct.pack("<IHHiIII", PCAP_MAGIC_US, 2, 4, 0, 0, 65535, LINKTYPE_ETHERNET))
        for i, item in enumerate(packets):
            dst_port, payload = (port, item) if isinstance(item, (bytes, bytearray)) else item
            frame = udp_frame(bytes(payload), dst_port=dst_port, ident=i)
            stamp = timestamps_s[i] if timestamps_s is not None else start_time_s + i * packet_period_s
            sec = int(stamp)
            usec = int(round((stamp - sec) * 1e6))
            if usec >= 1_000_000:
                sec, usec = sec + 1, usec - 1_000_000
            f.write(struct.pack("<IIII", sec, usec, len(frame), len(frame)))
            f.write(frame)
    return path
