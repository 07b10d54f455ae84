"""ROS bags (ROS 2 sqlite3 or MCAP storage, ROS 1 ``.bag``) replayed as a sensor (driver ``"rosbag"``).

A bag is a ROS 2 bag folder (``metadata.yaml`` beside ``.db3`` or ``.mcap`` files),
a single ``.mcap`` or ``.db3`` file, or a ROS 1 ``.bag`` file (most Livox recordings:
livox_ros_driver is a ROS 1 package); it is read with rosbags'
:class:`~rosbags.highlevel.AnyReader` (pure Python, no ROS install), which reads both
generations behind one interface: ROS 1 messages deserialise to the same types, with
``header.stamp`` as ``sec``/``nanosec``.

One :class:`RosbagSource` replays one topic, optionally within a time window,
one message per :meth:`RosbagSource.read`:

========================================  ==================================================
message type                              :class:`~backend.devices.base.Sample` field
========================================  ==================================================
``sensor_msgs/msg/Image``                 ``image`` (uint8 gray or BGR)
``sensor_msgs/msg/Image`` depth           ``depth`` (H, W) m, ``points`` (N, 3) m: a depth sample (below)
``sensor_msgs/msg/CompressedImage``       ``image`` (uint8 gray or BGR)
``sensor_msgs/msg/PointCloud2``           ``points`` (N, 3) m, ``intensity`` when present
``sensor_msgs/msg/LaserScan``             ``points`` (N, 3) m with z = 0, ``intensity``
``sensor_msgs/msg/CameraInfo``            ``meta["intrinsics"]`` (CameraIntrinsics.to_dict())
``sensor_msgs/msg/Imu``                   ``imu``: :class:`~backend.core.imu.ImuSamples` of one sample
Livox ``CustomMsg`` (below)               ``points`` (N, 3) m, ``intensity`` (reflectivity 0-255),
                                          ``meta["point_time_s"]``
========================================  ==================================================

An IMU topic replays one message per read, as every other topic does (so ``index``, ``bag_time_s`` and the time
window mean the same for it, and a message that cannot be used fails alone); a solve wants the whole stream at once:
:func:`read_imu_topic` reads a topic into one checked :class:`~backend.core.imu.ImuSamples`
(:func:`~backend.core.imu.checked_imu`), as :func:`~backend.devices.imu_csv.read_imu_csv` reads a CSV file.

Livox ``CustomMsg`` (livox_ros_driver, livox_ros_driver2 and livox_ros2_driver's ``livox_interfaces``: one layout,
``header, uint64 timebase (ns), uint32 point_num, uint8 lidar_id, uint8[3] rsvd, CustomPoint[] points`` with
``CustomPoint: uint32 offset_time (ns after timebase), float32 x, y, z (m), uint8 reflectivity, tag, line``) replays
as its points in the LiDAR's frame, ``timestamp_s`` the time base (the first point's time; the header stamp when the
time base is 0) and ``meta["point_time_s"]`` each point's time in s after ``timestamp_s``. These types are not in
rosbags' type store: :func:`typestore` adds them, for bags that carry no message definitions (ROS 1 bags and MCAP
files carry their own) and for writing such bags.

The message conversions are public, vectorised numpy functions usable on any
deserialised message (:func:`pointcloud2_to_points`, :func:`laserscan_to_points`,
:func:`image_to_array`, :func:`compressed_image_to_array`,
:func:`camera_info_to_intrinsics`, :func:`depth_image_to_metres`, :func:`imu_to_arrays`,
:func:`custom_msg_to_points`); :func:`list_topics` lists what a bag holds.

Depth images (REP 118: ``16UC1`` in millimetres, ``32FC1`` in metres, 0 or NaN = no return) replay as depth
samples (:func:`~backend.devices.depth_files.depth_sample`: ``depth``, ``points`` in the camera's optical frame,
``meta["intrinsics"]``, ``meta["pixel_index"]``) when their camera is known: from the ``camera_info_topic``
setting, or else the ``camera_info`` topic beside the image topic (``/cam/depth/image_raw`` →
``/cam/depth/camera_info``). The first CameraInfo message gives K and the plumb_bob distortion (the image is
undistorted onto K's pinhole); it is taken as constant over the bag. Without a camera a ``16UC1`` image replays as
a gray image as before and a ``32FC1`` one raises an error saying which CameraInfo topic is missing.

Bad input raises :class:`RosbagError`, which is both an
:class:`~backend.core.errors.InputError` (so the API and CLI report it as a 4xx /
one-line error naming the bag) and a :class:`~backend.devices.base.DeviceError`
(so live capture reports a device that cannot be opened): a missing, unknown,
truncated or corrupt file, a topic the bag does not hold (the message lists the
topics it does hold, with their types) and an unsupported message type. Nothing
is changed anywhere by a failed open.
"""

from __future__ import annotations

import contextlib
import functools
import posixpath
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from backend.core.camera import CameraIntrinsics
from backend.core.depth import DepthIntrinsics
from backend.core.errors import InputError
from backend.core.imu import ImuSamples, checked_imu
from backend.devices.base import (
    CaptureDevice,
    DeviceDisconnected,
    DeviceError,
    RecordingError,
    Sample,
    register_driver,
)
from backend.devices.depth_files import MM_PER_M, check_ranges, depth_sample, pinhole_of, undistort_depth
from backend.devices.image_io import check_pixels, image_size

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
LASERSCAN = "sensor_msgs/msg/LaserScan"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
IMU = "sensor_msgs/msg/Imu"
LIVOX_CUSTOM_MSGS = ("livox_ros_driver/msg/CustomMsg", "livox_ros_driver2/msg/CustomMsg",
                     "livox_interfaces/msg/CustomMsg")
"""Livox's point-cloud message in its three packages (ROS 1 driver, SDK 2 driver, ROS 2 driver for SDK 1)."""
SUPPORTED_TYPES = (IMAGE, COMPRESSED_IMAGE, POINTCLOUD2, LASERSCAN, CAMERA_INFO, IMU, *LIVOX_CUSTOM_MSGS)
"""Message types :class:`RosbagSource` can replay."""

BAG_FILE_SUFFIXES = (".mcap", ".db3", ".bag")
"""Single-file bags accepted besides ROS 2 bag folders (``.bag``: ROS 1)."""

LIVOX_CUSTOM_MSG = """std_msgs/Header header
uint64 timebase
uint32 point_num
uint8 lidar_id
uint8[3] rsvd
CustomPoint[] points
"""
"""``CustomMsg.msg`` as Livox-SDK/livox_ros_driver2 (and livox_ros_driver, livox_interfaces) define it."""
LIVOX_CUSTOM_POINT = """uint32 offset_time
float32 x
float32 y
float32 z
uint8 reflectivity
uint8 tag
uint8 line
"""
"""``CustomPoint.msg``: ``offset_time`` in ns after the message's ``timebase``, x, y, z in m."""

MAX_IMU_MESSAGES = 5_000_000
"""Most messages :func:`read_imu_topic` reads from one topic (7 h at 200 Hz), checked on the bag's count first."""

_POINTFIELD_DTYPES: dict[int, str] = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
"""sensor_msgs/PointField datatype constants (INT8 … FLOAT64) to numpy type codes (no byte order)."""

INTENSITY_FIELDS = ("intensity", "intensities", "i")
"""PointCloud2 field names taken as the return intensity, first match wins."""

IMAGE_ENCODINGS = ("mono8", "8UC1", "mono16", "16UC1", "rgb8", "bgr8", "8UC3", "rgba8", "bgra8", "8UC4")
"""sensor_msgs/Image encodings :func:`image_to_array` understands."""
DEPTH_ENCODINGS = {"16UC1": 1.0 / MM_PER_M, "32FC1": 1.0}
"""Depth image encodings (REP 118) and the metres per stored unit of each."""


class RosbagError(RecordingError):
    """A bag that cannot be used as asked; ``input`` (and ``device``) name the bag."""


@dataclass
class TopicInfo:
    """One topic of a bag, as :func:`list_topics` reports it."""

    name: str
    msgtype: str
    """ROS 2 type name (ROS 1 types are named the same way), e.g. ``"sensor_msgs/msg/PointCloud2"``."""
    count: int
    """Number of messages on the topic."""
    start_s: float | None
    """Receive time of the first message, seconds after the bag start (None without messages)."""
    end_s: float | None
    """Receive time of the last message, seconds after the bag start (None without messages)."""
    bag_start_s: float
    """The bag start (receive time of its first message on any topic), seconds since the epoch."""
    supported: bool
    """Whether :class:`RosbagSource` can replay this type (see :data:`SUPPORTED_TYPES`)."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


# --------------------------------------------------------------------------------------------
# Opening bags


def _storage_path(bag_path: Path) -> Path:
    """The path to hand to rosbags: the bag folder, or its single storage file when it lacks metadata."""
    name = str(bag_path)
    if not bag_path.exists():
        raise RosbagError(f"bag {name} does not exist; expected a ROS 2 bag folder, a .mcap, a .db3 or a ROS 1 "
                          ".bag file", name)
    if bag_path.is_dir():
        if (bag_path / "metadata.yaml").is_file():
            return bag_path
        files = sorted(p for p in bag_path.iterdir() if p.suffix in BAG_FILE_SUFFIXES and p.is_file())
        if len(files) == 1:
            return files[0]
        raise RosbagError(
            f"folder {name} is not a ROS 2 bag: it has no metadata.yaml"
            + (f" and {len(files)} storage files" if files else " and no .mcap, .db3 or .bag file"),
            name,
        )
    if bag_path.suffix not in BAG_FILE_SUFFIXES:
        raise RosbagError(
            f"unknown file {name}: expected a ROS 2 bag folder (with metadata.yaml), a .mcap, a .db3 or a ROS 1 "
            ".bag file", name
        )
    return bag_path


def _corrupt(bag_path: Path, exc: BaseException) -> RosbagError:
    detail = str(exc).strip() or type(exc).__name__
    return RosbagError(f"bag {bag_path} is truncated or corrupt, or not a ROS 2 bag or ROS 1 bag ({detail})",
                       str(bag_path))


@contextlib.contextmanager
def _bag_errors(bag_path: Path) -> Iterator[None]:
    """Turn whatever the storage layer raises on a damaged file into a :class:`RosbagError`."""
    try:
        yield
    except (RosbagError, DeviceDisconnected):
        raise
    except Exception as exc:  # rosbags, sqlite3, struct, zstd, lz4 … all signal a bad file differently
        raise _corrupt(bag_path, exc) from exc


@functools.cache
def _livox_types() -> dict[str, Any]:
    """The Livox CustomMsg and CustomPoint definitions of every package in :data:`LIVOX_CUSTOM_MSGS`."""
    from rosbags.typesys import get_types_from_msg

    types: dict[str, Any] = {}
    for msgtype in LIVOX_CUSTOM_MSGS:
        package = msgtype.split("/")[0]
        types |= get_types_from_msg(LIVOX_CUSTOM_POINT, f"{package}/msg/CustomPoint")
        types |= get_types_from_msg(LIVOX_CUSTOM_MSG, msgtype)
    return types


def typestore(ros1: bool = False) -> Any:
    """rosbags' type store of ROS 2 Humble (or of ROS 1 Noetic, to write ROS 1 bags) with the Livox CustomMsg types
    added: what bags without their own message definitions are read with."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    store.register(_livox_types())
    return store


def _open_reader(bag_path: Path) -> Any:
    """An opened AnyReader on the bag; :class:`RosbagError` naming the file if it cannot be read."""
    from rosbags.highlevel import AnyReader

    storage = _storage_path(bag_path)
    with _bag_errors(bag_path):
        reader = AnyReader([storage], default_typestore=typestore())
        reader.open()
    return reader


def _sibling_info(topic: str) -> str:
    """The ``camera_info`` topic beside an image topic, as ROS camera drivers publish it."""
    return posixpath.join(posixpath.dirname(topic) or "/", "camera_info")


def _topics_text(reader: Any) -> str:
    topics = reader.topics
    if not topics:
        return "the bag holds no topics"
    return "available topics: " + ", ".join(f"{name} ({info.msgtype})" for name, info in sorted(topics.items()))


def list_topics(bag_path: Path | str) -> list[TopicInfo]:
    """The topics of a bag, sorted by name, with type, message count and first/last receive time.

    ``bag_path`` is a ROS 2 bag folder (sqlite3 or MCAP storage), a single ``.mcap``
    or ``.db3`` file, or a ROS 1 ``.bag`` file. The per-topic times need one pass over the messages
    (their payloads are read but not deserialised). Raises :class:`RosbagError`
    naming the file if it is missing, unknown, truncated or corrupt.
    """
    bag_path = Path(bag_path)
    reader = _open_reader(bag_path)
    try:
        with _bag_errors(bag_path):
            bag_start = reader.start_time if reader.message_count else 0
            first: dict[str, int] = {}
            last: dict[str, int] = {}
            for connection, timestamp, _ in reader.messages():
                topic = connection.topic
                if topic not in first or timestamp < first[topic]:
                    first[topic] = timestamp
                if topic not in last or timestamp > last[topic]:
                    last[topic] = timestamp
            result = []
            for name, info in sorted(reader.topics.items()):
                msgtype = info.msgtype or "(mixed types)"
                result.append(TopicInfo(
                    name=name,
                    msgtype=msgtype,
                    count=int(info.msgcount),
                    start_s=(first[name] - bag_start) * 1e-9 if name in first else None,
                    end_s=(last[name] - bag_start) * 1e-9 if name in last else None,
                    bag_start_s=bag_start * 1e-9,
                    supported=msgtype in SUPPORTED_TYPES,
                ))
            return result
    finally:
        with contextlib.suppress(Exception):
            reader.close()


def _imu_topics_text(reader: Any) -> str:
    imu_topics = sorted(name for name, info in reader.topics.items() if info.msgtype == IMU)
    if not imu_topics:
        return f"it holds no {IMU} topic; {_topics_text(reader)}"
    return f"its {IMU} topics: {', '.join(imu_topics)}"


def read_imu_topic(bag_path: Path | str, topic: str) -> tuple[ImuSamples, list[str]]:
    """The sensor_msgs/Imu messages of ``topic`` as one :class:`~backend.core.imu.ImuSamples` (times: header stamps,
    s since the epoch, or the receive time where a stamp is 0; in receive order) and the warnings they earn, checked by
    :func:`~backend.core.imu.checked_imu` as an IMU CSV file is.

    Raises :class:`RosbagError` naming the bag (and the topic, and the time where it applies) for a bad bag, a topic
    it lacks or of another type (the message lists the bag's IMU topics), more than :data:`MAX_IMU_MESSAGES`
    messages, and a stream no solve can use (too few samples, time stamps that run backwards or repeat, a quantity
    not measured); gaps are warned, naming the bag, the topic and where.
    """
    bag_path = Path(bag_path)
    name = str(bag_path)
    reader = _open_reader(bag_path)
    try:
        with _bag_errors(bag_path):
            connections = [c for c in reader.connections if c.topic == topic]
            if not connections:
                raise RosbagError(f"bag {name} has no IMU topic {topic!r}; {_imu_topics_text(reader)}", name)
            other = sorted({c.msgtype for c in connections} - {IMU})
            if other:
                raise RosbagError(f"topic {topic!r} in bag {name} has message type {', '.join(other)}, not {IMU}; "
                                  f"{_imu_topics_text(reader)}", name)
            count = sum(int(c.msgcount) for c in connections)
            if count > MAX_IMU_MESSAGES:
                raise RosbagError(f"topic {topic!r} in bag {name} holds {count:,} IMU messages, more than the "
                                  f"{MAX_IMU_MESSAGES:,} one solve reads; cut the bag to the calibration run", name)
            received_ns, msgs = [], []
            for connection, timestamp, raw in reader.messages(connections=connections):
                received_ns.append(timestamp)
                msgs.append(reader.deserialize(raw, connection.msgtype))
    finally:
        with contextlib.suppress(Exception):
            reader.close()
    shown = f"bag {name} topic {topic}"
    try:
        stamps_s, gyro, accel = imu_to_arrays(msgs, shown)
        t_s = np.where(stamps_s > 0, stamps_s, np.array(received_ns, np.float64) * 1e-9)  # as a replay times them
        return checked_imu(t_s, gyro, accel, shown)
    except InputError as exc:
        raise RosbagError(exc.message, name) from None


# --------------------------------------------------------------------------------------------
# Message conversions


def stamp_to_s(stamp: Any) -> float:
    """A ``builtin_interfaces/Time`` as seconds (float)."""
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def _where(msg: Any, source: str | None, kind: str) -> str:
    """``"TOPIC at stamp 12.345000 s"`` to start error messages (``kind`` when no source is given).

    The errors' ``input`` is the topic (``source``) alone, the stamp is in the message.
    """
    try:
        at = f" at stamp {stamp_to_s(msg.header.stamp):.6f} s"
    except AttributeError:
        at = ""
    return f"{source or kind}{at}"


def pointcloud2_to_points(msg: Any, source: str | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Points (N, 3) float64 (m, the cloud's frame) and intensity (N,) float32 or None of a PointCloud2.

    Honours ``fields`` (name, offset, datatype), ``point_step``, ``row_step`` and
    ``is_bigendian``; other fields (padding, ring, time …) are ignored. Points with
    a non-finite x, y or z (NaN marks "no return" in organised clouds) are dropped,
    together with their intensity. ``source`` (e.g. the topic) names the input in
    errors. Raises :class:`~backend.core.errors.InputError` if x, y or z is missing
    or the data is shorter than the header says.
    """
    where = _where(msg, source, "PointCloud2")
    label = source or "PointCloud2"
    fields = {f.name: f for f in msg.fields}
    missing = [axis for axis in "xyz" if axis not in fields]
    if missing:
        raise InputError(
            f"{where}: PointCloud2 has no {', '.join(missing)} field (fields: {', '.join(fields) or 'none'})", label
        )
    intensity_name = next((name for name in INTENSITY_FIELDS if name in fields), None)
    wanted = ["x", "y", "z"] + ([intensity_name] if intensity_name else [])
    order = ">" if msg.is_bigendian else "<"
    point_step = int(msg.point_step)
    width, height = int(msg.width), int(msg.height)
    formats = []
    for name in wanted:
        field = fields[name]
        code = _POINTFIELD_DTYPES.get(int(field.datatype))
        if code is None:
            raise InputError(f"{where}: field {name!r} has unknown PointField datatype {field.datatype}", label)
        if int(field.offset) + np.dtype(code).itemsize > point_step:
            raise InputError(f"{where}: field {name!r} at offset {field.offset} does not fit point_step "
                             f"{point_step}", label)
        formats.append(order + code)
    dtype = np.dtype({"names": wanted, "formats": formats,
                      "offsets": [int(fields[n].offset) for n in wanted], "itemsize": point_step})
    n_points = width * height
    if n_points == 0:
        return np.zeros((0, 3)), (np.zeros(0, np.float32) if intensity_name else None)
    data = np.asarray(msg.data, dtype=np.uint8).ravel()
    row_step = int(msg.row_step) or width * point_step
    if row_step < width * point_step or data.size < (height - 1) * row_step + width * point_step:
        raise InputError(
            f"{where}: PointCloud2 data holds {data.size} bytes, fewer than {height} rows x {width} points "
            f"x {point_step} bytes (row_step {row_step}) need", label)
    if height > 1 and row_step != width * point_step:  # drop the padding at the end of each row
        if data.size < height * row_step:  # the last row may come without its padding
            data = np.concatenate([data, np.zeros(height * row_step - data.size, np.uint8)])
        data = np.ascontiguousarray(data[: height * row_step].reshape(height, row_step)[:, : width * point_step])
    records = np.frombuffer(np.ascontiguousarray(data).ravel()[: n_points * point_step], dtype=dtype)
    points = np.column_stack([records["x"], records["y"], records["z"]]).astype(np.float64)
    keep = np.isfinite(points).all(axis=1)
    intensity = records[intensity_name].astype(np.float32)[keep] if intensity_name else None
    return points[keep], intensity


def laserscan_to_points(msg: Any, source: str | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Points (N, 3) float64 in the scanner frame (m, z = 0) and intensity (N,) float32 or None of a LaserScan.

    Beam ``i`` points at ``angle_min + i * angle_increment`` (rad, counter-clockwise
    from x); beams whose range is non-finite or outside ``[range_min, range_max]``
    are dropped. Intensity is returned when the scan has one per beam.
    """
    del source  # no conversion here can fail; kept for a uniform signature
    ranges = np.asarray(msg.ranges, dtype=np.float64).ravel()
    angles = float(msg.angle_min) + np.arange(ranges.size) * float(msg.angle_increment)
    with np.errstate(invalid="ignore"):
        keep = np.isfinite(ranges) & (ranges >= float(msg.range_min)) & (ranges <= float(msg.range_max))
    r, a = ranges[keep], angles[keep]
    points = np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros_like(r)])
    raw_intensity = np.asarray(msg.intensities, dtype=np.float32).ravel()
    intensity = raw_intensity[keep] if raw_intensity.size == ranges.size else None
    return points, intensity


def _to_8bit(image: np.ndarray) -> np.ndarray:
    """A 16-bit image scaled so its maximum becomes 255 (zero stays zero); uint8 passes through."""
    if image.dtype == np.uint8:
        return image
    peak = float(image.max()) if image.size else 0.0
    if peak <= 0:
        return np.zeros(image.shape, np.uint8)
    return np.clip(np.rint(image.astype(np.float64) * (255.0 / peak)), 0, 255).astype(np.uint8)


def _unpack_rows(msg: Any, channels: int, base: np.dtype, where: str, label: str) -> np.ndarray:
    """The (height, width, channels) pixels of a sensor_msgs/Image of ``channels`` values of type ``base`` (byte
    order included) per pixel, its row padding (``step`` beyond a row) removed."""
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    row_bytes = width * channels * base.itemsize
    step = step or row_bytes
    data = np.asarray(msg.data, dtype=np.uint8).ravel()
    if step < row_bytes or data.size < (height - 1) * step + row_bytes or height * width == 0:
        raise InputError(
            f"{where}: {msg.encoding} image data holds {data.size} bytes, too few for {width}x{height} "
            f"(step {step})", label)
    if data.size < height * step:
        data = np.concatenate([data, np.zeros(height * step - data.size, np.uint8)])
    rows = data[: height * step].reshape(height, step)[:, :row_bytes]
    return np.ascontiguousarray(rows).view(base).reshape(height, width, channels)


def image_to_array(msg: Any, source: str | None = None, *, to_8bit: bool = False) -> np.ndarray:
    """The pixels of a sensor_msgs/Image: HxW gray or HxWx3 BGR, a copy that owns its memory.

    Encodings: ``mono8``/``8UC1`` → uint8 HxW; ``mono16``/``16UC1`` → **uint16** HxW
    (kept at full depth, honouring ``is_bigendian``) unless ``to_8bit``, which scales
    the image so its maximum becomes 255 (what board detection needs; the driver does
    this so its samples are always uint8); ``bgr8``/``8UC3`` → BGR; ``rgb8`` → BGR;
    ``bgra8``/``rgba8``/``8UC4`` → BGR (alpha dropped). Row padding (``step`` larger
    than a row) is removed. Other encodings (Bayer, float, YUV) raise
    :class:`~backend.core.errors.InputError` naming ``source`` and the encoding.
    """
    where = _where(msg, source, "Image")
    label = source or "Image"
    encoding = str(msg.encoding)
    if encoding in ("mono8", "8UC1"):
        channels, base = 1, np.dtype(np.uint8)
    elif encoding in ("mono16", "16UC1"):
        channels, base = 1, np.dtype(">u2" if msg.is_bigendian else "<u2")
    elif encoding in ("rgb8", "bgr8", "8UC3"):
        channels, base = 3, np.dtype(np.uint8)
    elif encoding in ("rgba8", "bgra8", "8UC4"):
        channels, base = 4, np.dtype(np.uint8)
    else:
        raise InputError(
            f"{where}: image encoding {encoding!r} is not supported; expected one of {', '.join(IMAGE_ENCODINGS)}",
            label)
    pixels = _unpack_rows(msg, channels, base, where, label)
    if channels == 1:
        image = pixels[:, :, 0].astype(np.uint16 if base.itemsize == 2 else np.uint8)
        return _to_8bit(image) if to_8bit else image
    if encoding == "rgb8":
        return np.ascontiguousarray(pixels[:, :, ::-1])
    if encoding == "rgba8":
        return cv2.cvtColor(pixels, cv2.COLOR_RGBA2BGR)
    if channels == 4:
        return cv2.cvtColor(pixels, cv2.COLOR_BGRA2BGR)
    return pixels.copy()


def depth_image_to_metres(msg: Any, source: str | None = None) -> np.ndarray:
    """The depth (H, W) float32 in metres of a ``16UC1`` (mm) or ``32FC1`` (m) sensor_msgs/Image, honouring
    ``is_bigendian`` and row padding; other encodings raise :class:`~backend.core.errors.InputError` naming
    ``source``."""
    where = _where(msg, source, "Image")
    label = source or "Image"
    encoding = str(msg.encoding)
    if encoding not in DEPTH_ENCODINGS:
        raise InputError(f"{where}: image encoding {encoding!r} is not a depth image; expected "
                         f"{' or '.join(DEPTH_ENCODINGS)}", label)
    order = ">" if msg.is_bigendian else "<"
    base = np.dtype(order + ("u2" if encoding == "16UC1" else "f4"))
    pixels = _unpack_rows(msg, 1, base, where, label)[:, :, 0]
    return (pixels.astype(np.float32) * np.float32(DEPTH_ENCODINGS[encoding])).astype(np.float32)


def compressed_image_to_array(msg: Any, source: str | None = None) -> np.ndarray:
    """Decode a sensor_msgs/CompressedImage (JPEG, PNG, …) with ``cv2.imdecode``: uint8 HxW or HxWx3 BGR.

    A gray JPEG stays HxW, an alpha channel is dropped, a 16-bit PNG is scaled so its
    maximum becomes 255. Undecodable data (including ``compressedDepth`` payloads)
    raises :class:`~backend.core.errors.InputError` naming ``source`` and the stamp, as does an image of more
    pixels than :data:`~backend.core.limits.MAX_IMAGE_PIXELS` (read from its header, before decoding).
    """
    where = _where(msg, source, "CompressedImage")
    label = source or "CompressedImage"
    data = np.asarray(msg.data, dtype=np.uint8).ravel()
    encoded = data.tobytes()
    if image_size(encoded) is not None:  # its pixels are counted from the header before anything is decoded
        check_pixels(encoded, f"{where}: compressed image", label)
        image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    else:
        image = None
    if image is None:
        raise InputError(
            f"{where}: compressed image (format {str(msg.format)!r}, {data.size} bytes) could not be decoded; "
            "expected JPEG or PNG data", label)
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    elif image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    return _to_8bit(image)


def camera_info_to_intrinsics(msg: Any, source: str | None = None) -> CameraIntrinsics:
    """The :class:`~backend.core.camera.CameraIntrinsics` in a sensor_msgs/CameraInfo.

    ``plumb_bob`` → ``pinhole-radtan`` with ``[k1, k2, p1, p2, k3]`` (missing trailing
    coefficients are zero); ``equidistant`` → ``fisheye-equidistant`` with
    ``[k1, k2, k3, k4]``; an empty model with no (or all-zero) coefficients →
    ``pinhole-radtan`` without distortion. Other models (``rational_polynomial`` …),
    an all-zero K (an uncalibrated camera) or a zero image size raise
    :class:`~backend.core.errors.InputError` naming ``source``.
    """
    where = _where(msg, source, "CameraInfo")
    label = source or "CameraInfo"
    model_name = str(msg.distortion_model).strip()
    d = np.asarray(msg.d, dtype=np.float64).ravel()
    k = np.asarray(msg.k, dtype=np.float64).reshape(3, 3)
    if model_name == "plumb_bob" or (model_name == "" and not np.any(d)):
        if d.size > 5:
            raise InputError(f"{where}: plumb_bob distortion has {d.size} coefficients; expected at most 5", label)
        model, dist = "pinhole-radtan", d
    elif model_name == "equidistant":
        if d.size > 4:
            raise InputError(f"{where}: equidistant distortion has {d.size} coefficients; expected 4", label)
        model, dist = "fisheye-equidistant", d
    else:
        raise InputError(
            f"{where}: distortion model {model_name!r} is not supported; expected plumb_bob or equidistant", label)
    if not np.any(k):
        raise InputError(f"{where}: camera matrix K is all zeros (the camera is not calibrated)", label)
    if int(msg.width) <= 0 or int(msg.height) <= 0:
        raise InputError(f"{where}: image size {msg.width}x{msg.height} is empty", label)
    return CameraIntrinsics(model, int(msg.width), int(msg.height), k, dist)  # type: ignore[arg-type]


def imu_to_arrays(msgs: Sequence[Any], source: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Header stamps (N,) s, angular rates (N, 3) rad/s and specific forces (N, 3) m/s² of sensor_msgs/Imu
    messages, in the order given (the orientation is not used).

    REP 145 marks a quantity the IMU does not measure with ``-1`` as the first element of its covariance: such a
    message raises :class:`~backend.core.errors.InputError` naming ``source`` and the stamp, as no solve can use it.
    """
    for msg in msgs:
        for quantity in ("angular_velocity", "linear_acceleration"):
            if float(np.asarray(getattr(msg, f"{quantity}_covariance")).ravel()[0]) == -1.0:
                raise InputError(f"{_where(msg, source, 'Imu')}: the IMU does not report its {quantity} (its "
                                 "covariance starts with -1); expected angular rates and accelerations",
                                 source or "Imu")
    t_s = np.array([stamp_to_s(msg.header.stamp) for msg in msgs], dtype=np.float64)
    vectors = np.array([(m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z, m.linear_acceleration.x,
                         m.linear_acceleration.y, m.linear_acceleration.z) for m in msgs], np.float64).reshape(-1, 6)
    return t_s, vectors[:, :3], vectors[:, 3:]


def custom_msg_to_points(msg: Any, source: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (N, 3) float64 (m, the LiDAR's frame), reflectivity (N,) float32 (0-255) and each point's time
    after the message's ``timebase`` (N,) float64 s of a Livox CustomMsg (any of :data:`LIVOX_CUSTOM_MSGS`).

    Points at the origin (Livox's "no return") or with a non-finite coordinate are dropped with their reflectivity
    and time. ``source`` names the input in errors: :class:`~backend.core.errors.InputError` for a message whose
    ``point_num`` disagrees with the points it holds.
    """
    points = msg.points
    if int(msg.point_num) != len(points):
        raise InputError(f"{_where(msg, source, 'CustomMsg')}: CustomMsg point_num is {msg.point_num} but the "
                         f"message holds {len(points)} points", source or "CustomMsg")
    records = np.array([(p.offset_time, p.x, p.y, p.z, p.reflectivity) for p in points], np.float64).reshape(-1, 5)
    xyz = records[:, 1:4]
    keep = np.isfinite(xyz).all(axis=1) & xyz.any(axis=1)
    return xyz[keep], records[keep, 4].astype(np.float32), records[keep, 0] * 1e-9


# --------------------------------------------------------------------------------------------
# The driver


@register_driver
class RosbagSource(CaptureDevice):
    """Replays one topic of a ROS bag, one message per :meth:`read`, in receive order.

    ``path`` is a bag folder, a ``.mcap``, ``.db3`` or ROS 1 ``.bag`` file; ``topic`` one of its
    topics of a :data:`SUPPORTED_TYPES` type. ``start_s``/``end_s`` (seconds after the
    bag start, i.e. the receive time of its first message; both ends inclusive) limit
    the replay to a window of receive times; None means from the start / to the end.

    ``timestamp_s`` of a sample is the message's header stamp (seconds since the
    epoch), or its receive time when the stamp is zero. ``meta`` holds ``topic``,
    ``frame_id``, ``stamp_s`` (header stamp), ``bag_time_s`` (receive time),
    ``bag`` (the path), ``index`` (0-based position in the replay) and ``msgtype``;
    CameraInfo samples carry no image or points but ``meta["intrinsics"]``, the
    camera as :meth:`CameraIntrinsics.to_dict`. An Imu sample's ``imu`` holds its
    one sample at ``timestamp_s``. A Livox CustomMsg sample's ``timestamp_s`` is
    its ``timebase`` (when not 0), ``meta["point_time_s"]`` (N,) each point's time
    after it (s) and ``meta["lidar_id"]`` the LiDAR's number.

    Depth image topics (see the module docs) take ``camera_info_topic`` (default: the
    ``camera_info`` beside the topic) and ``min_range_m``/``max_range_m`` (m), the depth
    unprojected into points; their samples carry ``meta["undistorted_from"]`` too (the
    CameraInfo's camera).

    :meth:`open` raises :class:`RosbagError` (an InputError and a DeviceError) for a
    bad bag, a missing topic or an unsupported type. :meth:`read` raises
    :class:`~backend.core.errors.InputError` for one message that cannot be
    converted (the next ``read()`` continues), :class:`RosbagError` if the file turns
    out damaged mid-way (the replay then ends) and
    :class:`~backend.devices.base.DeviceDisconnected` after the last message.
    """

    driver = "rosbag"

    def __init__(self, path: str, topic: str, start_s: float | None = None, end_s: float | None = None,
                 camera_info_topic: str | None = None, min_range_m: float = DepthIntrinsics.min_range_m,
                 max_range_m: float = DepthIntrinsics.max_range_m):
        self.path = Path(path)
        self.topic = topic
        self.start_s = None if start_s is None else float(start_s)
        self.end_s = None if end_s is None else float(end_s)
        self.camera_info_topic = camera_info_topic or None
        self.min_range_m, self.max_range_m = check_ranges(min_range_m, max_range_m, str(path))
        self.depth_camera: CameraIntrinsics | None = None
        """The camera of a depth image topic, from its CameraInfo (known once open; None without one)."""
        self.msgtype: str | None = None
        self.message_count: int | None = None
        """Messages on the topic in the whole bag (known once open)."""
        self._reader: Any = None
        self._messages: Iterator[Any] | None = None
        self._index = 0

    def open(self) -> None:
        """Open the bag and position at the first message of the topic in the window."""
        self.close()
        name = str(self.path)
        if self.start_s is not None and self.end_s is not None and self.end_s < self.start_s:
            raise RosbagError(f"time window end {self.end_s} s is before its start {self.start_s} s", name)
        reader = _open_reader(self.path)
        try:
            with _bag_errors(self.path):
                connections = [c for c in reader.connections if c.topic == self.topic]
                if not connections:
                    raise RosbagError(f"bag {name} has no topic {self.topic!r}; {_topics_text(reader)}", name)
                msgtypes = sorted({c.msgtype for c in connections})
                unsupported = [t for t in msgtypes if t not in SUPPORTED_TYPES]
                if unsupported:
                    raise RosbagError(
                        f"topic {self.topic!r} in bag {name} has message type {', '.join(unsupported)}, which "
                        f"cannot be replayed; supported types: {', '.join(SUPPORTED_TYPES)}", name)
                self.depth_camera = (self._depth_camera(reader, self.camera_info_topic or _sibling_info(self.topic))
                                     if IMAGE in msgtypes else None)
                bag_start = reader.start_time
                start = None if self.start_s is None else bag_start + round(self.start_s * 1e9)
                stop = None if self.end_s is None else bag_start + round(self.end_s * 1e9) + 1
                self._messages = reader.messages(connections=connections, start=start, stop=stop)
        except BaseException:
            with contextlib.suppress(Exception):
                reader.close()
            raise
        self._reader = reader
        self.msgtype = msgtypes[0]
        self.message_count = sum(int(c.msgcount) for c in connections)
        self._index = 0

    def read(self) -> Sample:
        """Return the next message of the topic as a :class:`Sample` (see the class docs)."""
        if self._reader is None:
            raise DeviceError("not open; call open() first", str(self.path))
        if self._messages is None:
            raise DeviceDisconnected(self._end_text(), str(self.path))
        try:
            with _bag_errors(self.path):
                connection, timestamp, raw = next(self._messages)
                msg = self._reader.deserialize(raw, connection.msgtype)
        except StopIteration:
            self._messages = None
            raise DeviceDisconnected(self._end_text(), str(self.path)) from None
        except RosbagError:
            self._messages = None  # a damaged file: nothing after this point can be trusted
            raise
        index = self._index
        self._index += 1
        bag_time_s = timestamp * 1e-9
        header = getattr(msg, "header", None)
        stamp_s = stamp_to_s(header.stamp) if header is not None else 0.0
        meta: dict[str, Any] = {
            "topic": self.topic,
            "frame_id": str(header.frame_id) if header is not None else "",
            "stamp_s": stamp_s,
            "bag_time_s": bag_time_s,
            "bag": str(self.path),
            "index": index,
            "msgtype": connection.msgtype,
        }
        sample = Sample(timestamp_s=stamp_s if stamp_s > 0 else bag_time_s, meta=meta)
        source = self.topic
        if connection.msgtype == IMAGE and str(msg.encoding) in DEPTH_ENCODINGS and (
                self.depth_camera is not None or str(msg.encoding) == "32FC1"):
            return self._depth_sample(msg, sample)
        if connection.msgtype == IMAGE:
            sample.image = image_to_array(msg, source, to_8bit=True)
        elif connection.msgtype == COMPRESSED_IMAGE:
            sample.image = compressed_image_to_array(msg, source)
        elif connection.msgtype == POINTCLOUD2:
            sample.points, sample.intensity = pointcloud2_to_points(msg, source)
        elif connection.msgtype == LASERSCAN:
            sample.points, sample.intensity = laserscan_to_points(msg, source)
        elif connection.msgtype == CAMERA_INFO:
            meta["intrinsics"] = camera_info_to_intrinsics(msg, source).to_dict()
        elif connection.msgtype == IMU:
            _, gyro, accel = imu_to_arrays([msg], source)
            sample.imu = ImuSamples(np.array([sample.timestamp_s]), gyro, accel)
        elif connection.msgtype in LIVOX_CUSTOM_MSGS:
            sample.points, sample.intensity, meta["point_time_s"] = custom_msg_to_points(msg, source)
            meta["lidar_id"] = int(msg.lidar_id)
            if int(msg.timebase) > 0:
                sample.timestamp_s = int(msg.timebase) * 1e-9
        return sample

    def _depth_camera(self, reader: Any, info_topic: str) -> CameraIntrinsics | None:
        """The camera of the first message on ``info_topic``; None when the bag has no such CameraInfo topic
        and none was asked for (a :class:`RosbagError` when ``camera_info_topic`` names one it lacks)."""
        name = str(self.path)
        connections = [c for c in reader.connections if c.topic == info_topic and c.msgtype == CAMERA_INFO]
        if not connections:
            if self.camera_info_topic is None:
                return None
            raise RosbagError(f"bag {name} has no CameraInfo topic {info_topic!r} for the depth images on "
                              f"{self.topic}; {_topics_text(reader)}", name)
        for connection, _, raw in reader.messages(connections=connections):
            try:
                return camera_info_to_intrinsics(reader.deserialize(raw, connection.msgtype), info_topic)
            except InputError as exc:  # a camera it cannot use, not a damaged bag
                raise RosbagError(f"bag {name}: {exc.message}", name) from None
        raise RosbagError(f"CameraInfo topic {info_topic!r} in bag {name} holds no message", name)

    def _depth_sample(self, msg: Any, sample: Sample) -> Sample:
        """The depth sample of a depth image, ``sample``'s time stamp and meta kept."""
        where = _where(msg, self.topic, "Image")
        camera = self.depth_camera
        if camera is None:
            raise InputError(f"{where}: a {msg.encoding} depth image needs its camera: the bag has no CameraInfo "
                             f"topic {_sibling_info(self.topic)!r}; set camera_info_topic", self.topic)
        depth = depth_image_to_metres(msg, self.topic)
        if depth.shape != (camera.height, camera.width):
            raise InputError(f"{where}: the depth image is {depth.shape[1]}x{depth.shape[0]} px, its CameraInfo "
                             f"{camera.width}x{camera.height}", self.topic)
        depth, _ = undistort_depth(depth, None, camera)
        meta = {**sample.meta, "undistorted_from": camera.to_dict()}
        return depth_sample(depth, pinhole_of(camera, self.min_range_m, self.max_range_m), sample.timestamp_s,
                            self.topic, None, meta)

    def _end_text(self) -> str:
        window = ""
        if self.start_s is not None or self.end_s is not None:
            lo = "start" if self.start_s is None else f"{self.start_s:g} s"
            hi = "end" if self.end_s is None else f"{self.end_s:g} s"
            window = f" in the window {lo} to {hi}"
        return f"end of bag after {self._index} messages on {self.topic}{window}"

    def close(self) -> None:
        """Close the bag; safe to call twice."""
        messages, self._messages = self._messages, None
        if messages is not None:
            with contextlib.suppress(Exception):
                messages.close()  # type: ignore[attr-defined]
        reader, self._reader = self._reader, None
        if reader is not None:
            with contextlib.suppress(Exception):
                reader.close()

    def describe(self) -> str:
        count = f" ({self.message_count} messages)" if self.message_count is not None else ""
        return f"{self.driver} {self.path} {self.topic}{count}"
