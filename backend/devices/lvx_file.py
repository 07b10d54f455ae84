"""Livox ``.lvx`` recordings (LVX 1.1: Livox Viewer and the Livox SDK 1 samples) replayed frame by frame as a LiDAR
(driver ``"lvx"``), read into one cloud accumulated over a time window (:func:`read_lvx_cloud`, which
:func:`~backend.devices.cloud_files.read_cloud` uses for ``.lvx`` files), and their built-in IMU read as IMU samples
(:func:`read_lvx_imu`).

The layout (little-endian, packed; Livox-SDK ``sample/lidar_lvx_file/lvx_file.h``):

- the public header, 24 bytes: signature ``livox_tech`` (16 bytes, NUL-padded), version (4 bytes, ``1.1.0.0``),
  magic code ``0xAC0EA767``; the private header, 5 bytes: frame duration (uint32, ms), device count (uint8); then
  one 59-byte device info a device: LiDAR and hub broadcast codes, device index, device type
  (:data:`~backend.devices.livox_packets.LIVOX_MODELS`),
  extrinsic flag, roll, pitch, yaw (deg) and x, y, z (m). livox-lvx (``lvx.lvx.LvxHeader``) reads these;
- frames, each a 24-byte header (``current_offset``, ``next_offset``: byte offsets in the file; ``frame_index``) and
  packages up to ``next_offset``: a device index byte, then a Livox SDK 1 data packet as the LiDAR sent it over UDP
  (its 18-byte header and the fixed number of records of its data type).

livox-lvx's own package reader makes one Python object a point, reads the int32 millimetre coordinates as unsigned
and gives no point times; the packages are decoded here a whole frame at a time by the live driver's numpy decoders
(:mod:`backend.devices.livox_packets`): data types 2 (single return) and 4 (dual return: both returns, at their
firing's time) as points (m) with their reflectivity, 6 as IMU samples (rad/s, m/s²); other data types and protocol
versions are refused, naming them. Points at the origin (Livox's "no return") are dropped. Each point's time is its
package's time stamp plus its firing's point intervals (:func:`~backend.devices.livox_packets.packet_times_ns`,
:data:`~backend.devices.livox_packets.POINT_INTERVAL_NS` by the device type the file lists). A frame replays with
``timestamp_s`` its first point's time (s, on the LiDAR's clock) and ``meta["point_time_s"]`` each point's time
after it, as Livox CustomMsg topics replay (:mod:`backend.devices.rosbag_source`).

A recording of several LiDARs (a Livox Hub, or Livox Viewer with several sensors) interleaves their packages:
``device_index`` picks one (it is required then; the error lists the devices). Points are in the LiDAR's own frame:
the extrinsics in the device info are not applied.

Bad input raises :class:`LvxError` (an :class:`~backend.core.errors.InputError` and a
:class:`~backend.devices.base.DeviceError`, like :class:`~backend.devices.rosbag_source.RosbagError`) naming the
file: not an LVX file, an unknown version (LVX 2, written for the Mid-360 and HAP, included), a truncated or
corrupt frame, an unknown protocol version or data type, a device it does not list, a frame larger than
:data:`MAX_FRAME_BYTES`, and more points in a window than :data:`~backend.core.limits.MAX_CLOUD_POINTS`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from backend.core.errors import InputError
from backend.core.imu import ImuSamples, checked_imu
from backend.core.limits import MAX_CLOUD_POINTS
from backend.devices.base import (
    CaptureDevice,
    DeviceDisconnected,
    DeviceError,
    RecordingError,
    Sample,
    register_driver,
)
from backend.devices.livox_packets import (
    DATA_TYPE_IMU,
    ETH_HEADER,
    LIVOX_MODELS,
    POINT_INTERVAL_NS,
    RETURNS_PER_FIRING,
    check_data_header,
    data_headers,
    decode_imu,
    decode_points,
    packet_size,
    packet_times_ns,
)

LVX_SIGNATURE = b"livox_tech"
LVX_MAGIC = 0xAC0EA767
LVX_VERSION = (1, 1, 0, 0)
MAX_FRAME_BYTES = 64 * 1024 * 1024
"""Largest frame read (a 50 ms frame of an Avia in dual-return mode is about 350 kB)."""
FRAME_HEADER_BYTES = 24
DEVICE_INDEX_BYTES = 1
"""Before each package's data packet: the index of the device that sent it."""


class LvxError(RecordingError):
    """An .lvx file that cannot be used as asked; ``input`` (and ``device``) name the file."""


@dataclass(frozen=True)
class LvxDevice:
    """One LiDAR a recording lists."""

    index: int
    """The device index its packages carry."""
    device_type: int
    """Livox SDK 1 device type (:data:`LIVOX_MODELS`)."""
    broadcast_code: str

    @property
    def model(self) -> str:
        return LIVOX_MODELS.get(self.device_type, f"device type {self.device_type}")


@dataclass(frozen=True)
class LvxInfo:
    """What an .lvx file's headers say."""

    frame_duration_s: float
    devices: list[LvxDevice]
    first_frame_offset: int
    """Byte offset of the first frame."""
    size_bytes: int


@dataclass
class LvxFrame:
    """The packages of one frame, decoded; times are ns on the LiDAR's clock."""

    frame_index: int
    points: np.ndarray
    """(N, 3) float64 points (m) in their LiDAR's frame."""
    reflectivity: np.ndarray
    """(N,) float32, 0-255."""
    time_ns: np.ndarray
    """(N,) int64 each point's time."""
    point_device: np.ndarray
    """(N,) uint8 device index of each point."""
    imu_time_ns: np.ndarray
    """(M,) int64."""
    gyro_rad_s: np.ndarray
    """(M, 3)."""
    accel_m_s2: np.ndarray
    """(M, 3)."""
    imu_device: np.ndarray
    """(M,) uint8."""
    data_types: list[int]
    """The data types of its point packages."""
    timestamp_types: list[int]

    def of_device(self, index: int) -> LvxFrame:
        """The frame's points and IMU samples of device ``index`` alone."""
        p, m = self.point_device == index, self.imu_device == index
        return LvxFrame(self.frame_index, self.points[p], self.reflectivity[p], self.time_ns[p],
                        self.point_device[p], self.imu_time_ns[m], self.gyro_rad_s[m], self.accel_m_s2[m],
                        self.imu_device[m], self.data_types, self.timestamp_types)


# --------------------------------------------------------------------------------------------
# Headers


def read_lvx_info(path: Path | str) -> LvxInfo:
    """The headers of an .lvx file; :class:`LvxError` naming the file if it is not LVX 1.1."""
    from lvx.lvx import LvxHeader, LvxParseError

    path = Path(path)
    name = str(path)
    if not path.is_file():
        raise LvxError(f"{name} {'is a folder' if path.is_dir() else 'does not exist'}; expected an .lvx file", name)
    size = path.stat().st_size
    with path.open("rb") as fh:
        head = fh.read(24)
        if not head.startswith(LVX_SIGNATURE):
            raise LvxError(f"{name} is not an LVX file: it does not start with 'livox_tech'", name)
        version = tuple(head[16:20])
        if version != LVX_VERSION:
            shown = ".".join(str(v) for v in version)
            lvx2 = " (LVX 2, written for the Mid-360 and HAP, is not read)" if version[0] == 2 else ""
            raise LvxError(f"{name} is LVX version {shown}{lvx2}; expected 1.1.0.0 (Livox Viewer, Livox SDK 1)", name)
        fh.seek(0)
        try:
            header = LvxHeader.read_from(fh)
        except LvxParseError as exc:
            raise LvxError(f"{name} is truncated in its header ({exc}); expected an LVX 1.1 file", name) from None
        first_frame = fh.tell()
    if header.magic_code != LVX_MAGIC:
        raise LvxError(f"{name}: magic code {header.magic_code:#x}, expected {LVX_MAGIC:#x}; the file is corrupt", name)
    devices = [LvxDevice(d.device_index, d.device_type, d.lidar_broadcast_code.split(b"\0")[0].decode(errors="replace"))
               for d in header.devices]
    return LvxInfo(header.frame_duration * 1e-3, devices, first_frame, size)


def _device_list(info: LvxInfo) -> str:
    return ", ".join(f"{d.index} ({d.model} {d.broadcast_code})" for d in info.devices) or "none"


def _pick_device(info: LvxInfo, device_index: int | None, name: str) -> int:
    """``device_index``, checked against the devices the file lists; the only device when None."""
    indices = [d.index for d in info.devices]
    if device_index is None:
        if len(indices) == 1:
            return indices[0]
        raise LvxError(f"{name} holds {len(indices)} devices: choose one with device_index ({_device_list(info)})",
                       name)
    if device_index not in indices:
        raise LvxError(f"{name} has no device {device_index}; its devices: {_device_list(info)}", name)
    return device_index


# --------------------------------------------------------------------------------------------
# Frames


def _rows(buffer: np.ndarray, starts: np.ndarray, offset: int, width: int) -> np.ndarray:
    """(len(starts), width) uint8: the ``width`` bytes at ``starts + offset`` of ``buffer``."""
    return buffer[(starts + offset)[:, None] + np.arange(width)]


def decode_frame(data: bytes, info: LvxInfo, frame_index: int) -> LvxFrame:
    """The packages of one frame (its bytes after the frame header); :class:`ValueError` saying what is wrong with
    them (the caller names the file and the frame)."""
    head = DEVICE_INDEX_BYTES + ETH_HEADER.itemsize
    starts, pos = [], 0
    while pos < len(data):  # packages differ in size by data type: found one after the other
        if pos + head > len(data):
            raise ValueError(f"a package header at byte {pos} is cut short")
        packet = pos + DEVICE_INDEX_BYTES
        version, data_type = data[packet], data[packet + ETH_HEADER.fields["data_type"][1]]
        check_data_header(version, data_type)
        end = packet + packet_size(data_type)
        if end > len(data):
            raise ValueError(f"a data type {data_type} package at byte {pos} is cut short")
        starts.append(pos)
        pos = end
    buffer, at = np.frombuffer(data, np.uint8), np.array(starts, np.int64)
    device = buffer[at] if len(at) else np.zeros(0, np.uint8)
    headers = data_headers(_rows(buffer, at, DEVICE_INDEX_BYTES, ETH_HEADER.itemsize))
    intervals = {d.index: POINT_INTERVAL_NS.get(d.device_type, POINT_INTERVAL_NS[0]) for d in info.devices}
    unknown = sorted(set(device.tolist()) - set(intervals))
    if unknown:
        raise ValueError(f"packages of device {unknown[0]}, which the file does not list "
                         f"(devices: {', '.join(map(str, intervals)) or 'none'})")
    times = packet_times_ns(headers)
    points, reflectivity = [np.zeros((0, 3))], [np.zeros(0, np.float32)]
    time_ns, point_device = [np.zeros(0, np.int64)], [np.zeros(0, np.uint8)]
    for index in intervals:
        for data_type in RETURNS_PER_FIRING:
            rows = np.flatnonzero((device == index) & (headers["data_type"] == data_type))
            if not len(rows):
                continue
            records = decode_points(_rows(buffer, at[rows], head, packet_size(data_type) - ETH_HEADER.itemsize),
                                    data_type, intervals[index])
            points.append(records.points_m)
            reflectivity.append(records.reflectivity)
            time_ns.append(times[rows][records.packet] + records.offset_ns)
            point_device.append(np.full(len(records.points_m), index, np.uint8))
    is_imu = headers["data_type"] == DATA_TYPE_IMU
    gyro, accel = decode_imu(_rows(buffer, at[is_imu], head, packet_size(DATA_TYPE_IMU) - ETH_HEADER.itemsize))
    return LvxFrame(frame_index, np.concatenate(points), np.concatenate(reflectivity), np.concatenate(time_ns),
                    np.concatenate(point_device), times[is_imu], gyro, accel, device[is_imu],
                    sorted(set(headers["data_type"][~is_imu].tolist())),
                    sorted(set(headers["timestamp_type"].tolist())))


def lvx_frames(fh: BinaryIO, info: LvxInfo, name: str) -> Iterator[LvxFrame]:
    """The frames of an open .lvx file from its first, decoded; :class:`LvxError` naming the file (``name``) and the
    frame for a truncated or corrupt one."""
    pos = info.first_frame_offset
    fh.seek(pos)
    count = 0
    while pos < info.size_bytes:
        where = f"{name}: frame {count} at byte {pos}"
        head = fh.read(FRAME_HEADER_BYTES)
        if len(head) < FRAME_HEADER_BYTES:
            raise LvxError(f"{where} is truncated: its header is cut short at the end of the file", name)
        current, following, frame_index = np.frombuffer(head, "<u8").tolist()
        if current != pos or following < pos + FRAME_HEADER_BYTES:
            raise LvxError(f"{where} is corrupt: its header says it runs from byte {current} to {following}", name)
        if following - pos > MAX_FRAME_BYTES:
            raise LvxError(f"{where} claims {following - pos:,} bytes, more than the {MAX_FRAME_BYTES:,} a frame "
                           "may hold; the file is corrupt", name)
        if following > info.size_bytes:
            raise LvxError(f"{where} is truncated: it should end at byte {following:,}, the file ends at "
                           f"{info.size_bytes:,}", name)
        data = fh.read(following - pos - FRAME_HEADER_BYTES)
        try:
            frame = decode_frame(data, info, frame_index)
        except ValueError as exc:
            raise LvxError(f"{where}: {exc}", name) from None
        yield frame
        pos, count = following, count + 1


# --------------------------------------------------------------------------------------------
# Whole files


@dataclass
class LvxCloud:
    """The points of one LiDAR of an .lvx recording accumulated over a time window."""

    points: np.ndarray
    """(N, 3) float64 (m), the LiDAR's frame."""
    reflectivity: np.ndarray
    """(N,) float32, 0-255."""
    time_s: np.ndarray
    """(N,) float64 each point's time (s) after the recording's first package."""
    device: LvxDevice
    frames: int
    """Frames with points in the window."""


def read_lvx_cloud(path: Path | str, start_s: float | None = None, end_s: float | None = None,
                   device_index: int | None = None) -> LvxCloud:
    """The points of a recording's LiDAR (``device_index``; the only one when None) whose times lie in
    ``[start_s, end_s]`` (s after the recording's first package; None: from the start, to the end), accumulated.

    Raises :class:`LvxError` naming the file for what :class:`LvxSource` refuses, for a window without points, and
    for more points than :data:`~backend.core.limits.MAX_CLOUD_POINTS`.
    """
    path = Path(path)
    name = str(path)
    if start_s is not None and end_s is not None and end_s < start_s:
        raise LvxError(f"{name}: the time window ends ({end_s} s) before it starts ({start_s} s)", name)
    info = read_lvx_info(path)
    index = _pick_device(info, device_index, name)
    lo, hi = -np.inf if start_s is None else start_s, np.inf if end_s is None else end_s
    points, reflectivity, times = [], [], []
    t0_ns: int | None = None
    total = 0
    with path.open("rb") as fh:
        for frame in lvx_frames(fh, info, name):
            if t0_ns is None:  # the recording's first package, of any device
                t0_ns = min((int(t.min()) for t in (frame.time_ns, frame.imu_time_ns) if len(t)), default=None)
            own = frame.of_device(index)
            t_s = (own.time_ns - (t0_ns or 0)) * 1e-9
            keep = (t_s >= lo) & (t_s <= hi)
            if not keep.any():
                continue
            total += int(keep.sum())
            if total > MAX_CLOUD_POINTS.value():
                raise LvxError(f"{name}: the window holds more than {MAX_CLOUD_POINTS.describe()}; choose a "
                               "shorter one", name)
            points.append(own.points[keep])
            reflectivity.append(own.reflectivity[keep])
            times.append(t_s[keep])
    device = next(d for d in info.devices if d.index == index)
    if not points:
        window = "" if start_s is None and end_s is None else f" from {lo:g} s to {hi:g} s"
        raise LvxError(f"{name} holds no points of device {index} ({device.model}){window}", name)
    return LvxCloud(np.concatenate(points), np.concatenate(reflectivity), np.concatenate(times), device, len(points))


def read_lvx_imu(path: Path | str, device_index: int | None = None) -> tuple[ImuSamples, list[str]]:
    """The built-in IMU's samples (data type 6 packages) of a recording's LiDAR, times in s on the LiDAR's clock,
    accelerations in m/s², checked by :func:`~backend.core.imu.checked_imu` (errors and warnings name the file)."""
    path = Path(path)
    name = str(path)
    info = read_lvx_info(path)
    index = _pick_device(info, device_index, name)
    times, gyro, accel = [], [], []
    with path.open("rb") as fh:
        for frame in lvx_frames(fh, info, name):
            own = frame.of_device(index)
            times.append(own.imu_time_ns)
            gyro.append(own.gyro_rad_s)
            accel.append(own.accel_m_s2)
    t_ns = np.concatenate(times) if times else np.zeros(0, np.int64)
    try:
        return checked_imu(t_ns * 1e-9, np.concatenate(gyro) if gyro else np.zeros((0, 3)),
                           np.concatenate(accel) if accel else np.zeros((0, 3)), f"{name} (device {index})")
    except InputError as exc:
        raise LvxError(exc.message, name) from None


# --------------------------------------------------------------------------------------------
# The driver


@register_driver
class LvxSource(CaptureDevice):
    """Replays one LiDAR of an .lvx recording, one frame (the file's frame duration, 50 ms from Livox Viewer) per
    :meth:`read`.

    ``device_index`` picks the LiDAR (required when the file holds several). A sample carries ``points`` (N, 3) m,
    ``intensity`` (reflectivity), ``imu`` (the frame's IMU samples, None without any), ``timestamp_s`` (its first
    point's time, s on the LiDAR's clock; its first IMU sample's without points) and ``meta``: ``point_time_s`` (N,)
    each point's time after ``timestamp_s``, ``frame_index``, ``device_index``, ``model``, ``data_types`` (2 single
    return, 4 dual), ``timestamp_types`` and ``source`` (the file name).

    :meth:`open` raises :class:`LvxError` for a file that is not LVX 1.1 or a device it does not list; :meth:`read`
    raises :class:`LvxError` for a truncated or corrupt frame (the replay then ends) and
    :class:`~backend.devices.base.DeviceDisconnected` after the last frame.
    """

    driver = "lvx"

    def __init__(self, path: str, device_index: int | None = None):
        self.path = Path(path)
        self.device_index = None if device_index is None else int(device_index)
        self.info: LvxInfo | None = None
        """The file's headers (known once open)."""
        self._file: BinaryIO | None = None
        self._frames: Iterator[LvxFrame] | None = None
        self._device: LvxDevice | None = None
        self._count = 0

    def open(self) -> None:
        self.close()
        name = str(self.path)
        info = read_lvx_info(self.path)
        index = _pick_device(info, self.device_index, name)
        self._device = next(d for d in info.devices if d.index == index)
        self.info = info
        self._file = self.path.open("rb")
        self._frames = lvx_frames(self._file, info, name)
        self._count = 0

    def read(self) -> Sample:
        if self._file is None or self._device is None:
            raise DeviceError("not open; call open() first", str(self.path))
        if self._frames is None:
            raise DeviceDisconnected(self._end_text(), str(self.path))
        try:
            frame = next(self._frames).of_device(self._device.index)
        except StopIteration:
            self._frames = None
            raise DeviceDisconnected(self._end_text(), str(self.path)) from None
        except LvxError:
            self._frames = None  # nothing after a damaged frame can be trusted
            raise
        self._count += 1
        first = frame.time_ns[0] if len(frame.time_ns) else (frame.imu_time_ns[0] if len(frame.imu_time_ns) else 0)
        imu = (ImuSamples(frame.imu_time_ns * 1e-9, frame.gyro_rad_s, frame.accel_m_s2)
               if len(frame.imu_time_ns) else None)
        return Sample(timestamp_s=int(first) * 1e-9, points=frame.points, intensity=frame.reflectivity, imu=imu,
                      meta={"point_time_s": (frame.time_ns - first) * 1e-9, "frame_index": frame.frame_index,
                            "device_index": self._device.index, "model": self._device.model,
                            "data_types": frame.data_types, "timestamp_types": frame.timestamp_types,
                            "source": self.path.name})

    def _end_text(self) -> str:
        return f"end of recording after {self._count} frames"

    def close(self) -> None:
        self._frames = None
        file, self._file = self._file, None
        if file is not None:
            with contextlib.suppress(Exception):
                file.close()

    def describe(self) -> str:
        model = f" {self._device.model}" if self._device is not None else ""
        return f"{self.driver} {self.path}{model}"
