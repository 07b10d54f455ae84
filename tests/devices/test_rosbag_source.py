"""ROS 2 bags (sqlite3 and MCAP) replayed through the ``rosbag`` driver, written here with rosbags' Writer."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from backend.core.errors import InputError
from backend.devices.base import DeviceDisconnected, DeviceError, Sample, create_device
from backend.devices.rosbag_source import (
    RosbagError,
    RosbagSource,
    camera_info_to_intrinsics,
    compressed_image_to_array,
    image_to_array,
    list_topics,
    pointcloud2_to_points,
)

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types
T0_NS = 1_700_000_000 * 10**9
"""Receive time of the first message in every test bag."""
STEP_NS = 100_000_000
"""Messages on a topic are 0.1 s apart."""
FLOAT32 = 7
RNG = np.random.default_rng(7)

# --- what goes into the bags ---------------------------------------------------------------

CLOUD_XYZ = [RNG.uniform(-20, 20, (50, 3)).astype(np.float32) for _ in range(3)]
CLOUD_I = [RNG.uniform(0, 255, 50).astype(np.float32) for _ in range(3)]
for _cloud in CLOUD_XYZ:
    _cloud[[3, 17, 40], 1] = np.nan  # "no return" points
PADDED_XYZ = RNG.uniform(-5, 5, (20, 3)).astype(np.float32)
PADDED_I = RNG.uniform(0, 1, 20).astype(np.float32)
SCAN_RANGES = np.array([1.0, 2.0, np.inf, 0.05, 3.0, np.nan, 50.0, 4.0], np.float32)
SCAN_INTENSITY = np.arange(8, dtype=np.float32) * 10
MONO = RNG.integers(0, 256, (6, 10), dtype=np.uint8)
BGR = RNG.integers(0, 256, (5, 7, 3), dtype=np.uint8)
K = np.array([[600.0, 0, 320.5], [0, 605.0, 240.25], [0, 0, 1]])
D = [-0.25, 0.08, 0.001, -0.0005, 0.01]


def checkerboard(squares: int = 8, side: int = 40) -> np.ndarray:
    ys, xs = np.indices((squares * side, squares * side)) // side
    board = np.where((xs + ys) % 2 == 0, 255, 0).astype(np.uint8)
    return cv2.copyMakeBorder(board, 20, 20, 20, 20, cv2.BORDER_CONSTANT, value=255)


BOARD = checkerboard()


def header(t_ns: int, frame: str):
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9),
                                    frame_id=frame)


def point_field(name: str, offset: int, datatype: int = FLOAT32):
    return T["sensor_msgs/msg/PointField"](name=name, offset=offset, datatype=datatype, count=1)


def cloud_msg(t_ns: int, xyz: np.ndarray, intensity: np.ndarray):
    records = np.column_stack([xyz, intensity]).astype("<f4")
    return T["sensor_msgs/msg/PointCloud2"](
        header=header(t_ns, "lidar"), height=1, width=len(xyz),
        fields=[point_field("x", 0), point_field("y", 4), point_field("z", 8), point_field("intensity", 12)],
        is_bigendian=False, point_step=16, row_step=16 * len(xyz),
        data=records.view(np.uint8).ravel(), is_dense=False)


def padded_cloud_msg(t_ns: int):
    """Organised 4x5 cloud, 32-byte points: intensity before xyz, an unused float64 field and padding."""
    dtype = np.dtype({"names": ["intensity", "x", "y", "z", "t"], "formats": ["<f4", "<f4", "<f4", "<f4", "<f8"],
                      "offsets": [0, 8, 12, 16, 24], "itemsize": 32})
    records = np.zeros(20, dtype)
    records["x"], records["y"], records["z"] = PADDED_XYZ.T
    records["intensity"] = PADDED_I
    records["t"] = 123.0
    return T["sensor_msgs/msg/PointCloud2"](
        header=header(t_ns, "lidar"), height=4, width=5,
        fields=[point_field("intensity", 0), point_field("x", 8), point_field("y", 12), point_field("z", 16),
                point_field("t", 24, 8)],
        is_bigendian=False, point_step=32, row_step=32 * 5,
        data=records.view(np.uint8).ravel(), is_dense=True)


def scan_msg(t_ns: int):
    return T["sensor_msgs/msg/LaserScan"](
        header=header(t_ns, "laser"), angle_min=np.float32(-np.pi / 2), angle_max=np.float32(np.pi / 2),
        angle_increment=np.float32(np.pi / 7), time_increment=0.0, scan_time=0.1, range_min=0.1, range_max=30.0,
        ranges=SCAN_RANGES, intensities=SCAN_INTENSITY)


def image_msg(t_ns: int, pixels: np.ndarray, encoding: str, step_pad: int = 0):
    h, w = pixels.shape[:2]
    rows = pixels.reshape(h, -1)
    rows = np.concatenate([rows, np.zeros((h, step_pad), np.uint8)], axis=1)
    return T["sensor_msgs/msg/Image"](header=header(t_ns, "camera_optical"), height=h, width=w, encoding=encoding,
                                      is_bigendian=0, step=rows.shape[1], data=rows.ravel())


def compressed_msg(t_ns: int, data: np.ndarray, fmt: str = "jpeg"):
    return T["sensor_msgs/msg/CompressedImage"](header=header(t_ns, "camera_optical"), format=fmt,
                                                data=np.asarray(data, np.uint8).ravel())


def camera_info_msg(t_ns: int, model: str = "plumb_bob", d=D):
    P = np.zeros((3, 4))
    P[:, :3] = K
    return T["sensor_msgs/msg/CameraInfo"](
        header=header(t_ns, "camera_optical"), height=480, width=640, distortion_model=model,
        d=np.array(d, float), k=K.ravel(), r=np.eye(3).ravel(), p=P.ravel(), binning_x=0, binning_y=0,
        roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))


def write_bag(path: Path, storage: StoragePlugin) -> Path:
    """Every topic the tests read; on each topic message i is received at T0 + i * 0.1 s (+ a topic offset)."""
    ok, jpeg = cv2.imencode(".jpg", BOARD, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    topics: dict[str, tuple[str, list]] = {
        "/lidar/points": ("sensor_msgs/msg/PointCloud2",
                          [cloud_msg(0, x, i) for x, i in zip(CLOUD_XYZ, CLOUD_I, strict=True)]),
        "/lidar/padded": ("sensor_msgs/msg/PointCloud2", [padded_cloud_msg(0)]),
        "/scan": ("sensor_msgs/msg/LaserScan", [scan_msg(0), scan_msg(0)]),
        "/cam/mono": ("sensor_msgs/msg/Image", [image_msg(0, MONO, "mono8", step_pad=6)]),
        "/cam/bgr": ("sensor_msgs/msg/Image", [image_msg(0, BGR, "bgr8"), image_msg(0, BGR[..., ::-1], "rgb8")]),
        "/cam/compressed": ("sensor_msgs/msg/CompressedImage",
                            [compressed_msg(0, jpeg), compressed_msg(0, np.frombuffer(b"not a jpeg", np.uint8))]),
        "/cam/info": ("sensor_msgs/msg/CameraInfo", [camera_info_msg(0)]),
        "/chatter": ("std_msgs/msg/String", [T["std_msgs/msg/String"](data="hi")]),
    }
    with Writer(path, version=9, storage_plugin=storage) as writer:
        for offset, (topic, (msgtype, msgs)) in enumerate(topics.items()):
            connection = writer.add_connection(topic, msgtype, typestore=TS)
            for i, msg in enumerate(msgs):
                t_ns = T0_NS + i * STEP_NS + offset * 1000
                if hasattr(msg, "header"):
                    msg.header.stamp.sec, msg.header.stamp.nanosec = t_ns // 10**9 - 5, t_ns % 10**9
                writer.write(connection, t_ns, TS.serialize_cdr(msg, msgtype))
    return path


@pytest.fixture(scope="module", params=[StoragePlugin.SQLITE3, StoragePlugin.MCAP], ids=["sqlite3", "mcap"])
def bag(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_bag(tmp_path_factory.mktemp("bags") / "rig", request.param)


def read_all(settings: dict) -> tuple[list[Sample], str]:
    device = create_device({"driver": "rosbag", **settings})
    samples = []
    with device:
        while True:
            try:
                samples.append(device.read())
            except DeviceDisconnected as exc:
                return samples, str(exc)


# --- reading each message type --------------------------------------------------------------


def test_pointcloud2_points_and_intensity_nan_dropped(bag: Path) -> None:
    samples, end = read_all({"path": str(bag), "topic": "/lidar/points"})
    assert len(samples) == 3
    assert "end of bag after 3 messages on /lidar/points" in end
    for i, sample in enumerate(samples):
        keep = np.isfinite(CLOUD_XYZ[i]).all(axis=1)
        assert keep.sum() == 47
        assert sample.points.dtype == np.float64 and sample.points.shape == (47, 3)
        np.testing.assert_array_equal(sample.points, CLOUD_XYZ[i][keep].astype(np.float64))
        assert sample.intensity.dtype == np.float32
        np.testing.assert_array_equal(sample.intensity, CLOUD_I[i][keep])
        assert sample.image is None
        t_ns = T0_NS + i * STEP_NS
        assert sample.meta["topic"] == "/lidar/points" and sample.meta["frame_id"] == "lidar"
        assert sample.meta["index"] == i and sample.meta["bag"] == str(bag)
        assert sample.meta["bag_time_s"] == pytest.approx(t_ns * 1e-9)
        assert sample.meta["stamp_s"] == pytest.approx(t_ns * 1e-9 - 5, abs=1e-6)
        assert sample.timestamp_s == sample.meta["stamp_s"]


def test_pointcloud2_with_padding_field_and_wide_point_step(bag: Path) -> None:
    (sample,), _ = read_all({"path": str(bag), "topic": "/lidar/padded"})
    np.testing.assert_array_equal(sample.points, PADDED_XYZ.astype(np.float64))
    np.testing.assert_array_equal(sample.intensity, PADDED_I)


def test_pointcloud2_big_endian_and_row_padding() -> None:
    xyz = RNG.uniform(-1, 1, (2, 3, 3))
    records = np.zeros((2, 3), np.dtype({"names": ["x", "y", "z"], "formats": [">f8"] * 3,
                                         "offsets": [0, 8, 16], "itemsize": 24}))
    records["x"], records["y"], records["z"] = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    rows = np.concatenate([records.view(np.uint8).reshape(2, 72), np.zeros((2, 8), np.uint8)], axis=1)
    msg = T["sensor_msgs/msg/PointCloud2"](
        header=header(0, "l"), height=2, width=3,
        fields=[point_field("x", 0, 8), point_field("y", 8, 8), point_field("z", 16, 8)],
        is_bigendian=True, point_step=24, row_step=80, data=rows.ravel(), is_dense=True)
    points, intensity = pointcloud2_to_points(msg, "/x")
    np.testing.assert_array_equal(points, xyz.reshape(-1, 3))
    assert intensity is None
    msg.fields = msg.fields[:2]
    with pytest.raises(InputError, match="no z field"):
        pointcloud2_to_points(msg, "/x")


def test_laserscan_geometry(bag: Path) -> None:
    samples, _ = read_all({"path": str(bag), "topic": "/scan"})
    assert len(samples) == 2
    angle_min, increment = np.float32(-np.pi / 2), np.float32(np.pi / 7)
    keep = [0, 1, 4, 7]  # inf, 0.05 < range_min, NaN and 50 > range_max are dropped
    r = SCAN_RANGES[keep].astype(np.float64)
    a = float(angle_min) + np.array(keep) * float(increment)
    expected = np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros(4)])
    np.testing.assert_allclose(samples[0].points, expected, atol=1e-12)
    np.testing.assert_array_equal(samples[0].intensity, SCAN_INTENSITY[keep])
    assert samples[0].meta["frame_id"] == "laser"


def test_images_mono8_with_row_padding_bgr8_and_rgb8(bag: Path) -> None:
    (mono,), _ = read_all({"path": str(bag), "topic": "/cam/mono"})
    assert mono.image.dtype == np.uint8
    np.testing.assert_array_equal(mono.image, MONO)
    bgr, rgb = read_all({"path": str(bag), "topic": "/cam/bgr"})[0]
    np.testing.assert_array_equal(bgr.image, BGR)
    np.testing.assert_array_equal(rgb.image, BGR)  # rgb8 comes back as BGR
    assert bgr.points is None


def test_image_encodings_mono16_and_rgba() -> None:
    mono16 = np.array([[0, 1000], [2000, 4000]], np.uint16)
    msg = T["sensor_msgs/msg/Image"](header=header(0, "c"), height=2, width=2, encoding="mono16", is_bigendian=1,
                                     step=4, data=mono16.astype(">u2").view(np.uint8).ravel())
    np.testing.assert_array_equal(image_to_array(msg), mono16)
    np.testing.assert_array_equal(image_to_array(msg, to_8bit=True), [[0, 64], [128, 255]])
    rgba = RNG.integers(0, 256, (3, 4, 4), dtype=np.uint8)
    msg = image_msg(0, rgba, "rgba8")
    np.testing.assert_array_equal(image_to_array(msg), rgba[..., 2::-1])
    msg.encoding = "bayer_rggb8"
    with pytest.raises(InputError, match="bayer_rggb8"):
        image_to_array(msg, "/cam")


def test_compressed_checkerboard_decodes_and_bad_data_names_topic_and_stamp(bag: Path) -> None:
    device = create_device({"driver": "rosbag", "path": str(bag), "topic": "/cam/compressed"})
    with device:
        sample = device.read()
        assert sample.image.shape == BOARD.shape  # a gray JPEG stays gray
        assert np.abs(sample.image.astype(int) - BOARD).mean() < 3
        found, corners = cv2.findChessboardCornersSB(sample.image, (7, 7))
        assert found and len(corners) == 49
        with pytest.raises(InputError) as info:
            device.read()
        assert "/cam/compressed" in info.value.message and "could not be decoded" in info.value.message
        assert f"{(T0_NS + STEP_NS + 5000) * 1e-9 - 5:.6f}" in info.value.message  # /cam/compressed is topic 5
        with pytest.raises(DeviceDisconnected, match="after 2 messages"):
            device.read()
    msg = compressed_msg(0, np.zeros(0, np.uint8))
    with pytest.raises(InputError):
        compressed_image_to_array(msg, "/c")


def test_a_compressed_image_bomb_is_refused_from_its_header() -> None:
    """A PNG whose header claims 16000x16000 px is refused before cv2 decodes (and allocates) anything."""
    ihdr = struct.pack(">IIBBBBB", 16000, 16000, 8, 0, 0, 0, 0)
    crc = struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
    header = b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IHDR" + ihdr + crc
    with pytest.raises(InputError) as info:
        compressed_image_to_array(compressed_msg(0, np.frombuffer(header, np.uint8), "png"), "/cam/compressed")
    assert info.value.status_code == 413 and info.value.input == "/cam/compressed"
    assert "16000x16000 px" in info.value.message and "CALIB_MAX_IMAGE_PIXELS" in info.value.message


def test_camera_info_to_intrinsics(bag: Path) -> None:
    (sample,), _ = read_all({"path": str(bag), "topic": "/cam/info"})
    camera = sample.meta["intrinsics"]
    assert camera["model"] == "pinhole-radtan" and (camera["width"], camera["height"]) == (640, 480)
    np.testing.assert_array_equal(camera["K"], K)
    np.testing.assert_array_equal(camera["dist"], D)
    assert sample.image is None and sample.points is None
    fisheye = camera_info_to_intrinsics(camera_info_msg(0, "equidistant", [0.1, -0.02, 0.003, -0.0004]))
    assert fisheye.model == "fisheye-equidistant"
    np.testing.assert_array_equal(fisheye.dist, [0.1, -0.02, 0.003, -0.0004])
    with pytest.raises(InputError, match="rational_polynomial"):
        camera_info_to_intrinsics(camera_info_msg(0, "rational_polynomial", [0.0] * 8), "/cam/info")


# --- choosing topics and time ranges ---------------------------------------------------------


def test_time_window_selects_messages(bag: Path) -> None:
    samples, end = read_all({"path": str(bag), "topic": "/lidar/points", "start_s": 0.05, "end_s": 0.2})
    assert [s.meta["index"] for s in samples] == [0, 1]
    np.testing.assert_array_equal(samples[0].intensity, CLOUD_I[1][np.isfinite(CLOUD_XYZ[1]).all(axis=1)])
    assert [s.meta["bag_time_s"] for s in samples] == pytest.approx([(T0_NS + k * STEP_NS) * 1e-9 for k in (1, 2)])
    assert "after 2 messages" in end and "window" in end
    assert len(read_all({"path": str(bag), "topic": "/lidar/points", "end_s": 0.1})[0]) == 2  # end is inclusive
    assert len(read_all({"path": str(bag), "topic": "/lidar/points", "start_s": 5.0})[0]) == 0


def test_list_topics(bag: Path) -> None:
    topics = {t.name: t for t in list_topics(bag)}
    assert sorted(topics) == ["/cam/bgr", "/cam/compressed", "/cam/info", "/cam/mono", "/chatter",
                              "/lidar/padded", "/lidar/points", "/scan"]
    points = topics["/lidar/points"]
    assert (points.msgtype, points.count) == ("sensor_msgs/msg/PointCloud2", 3)
    assert points.start_s == pytest.approx(0.0) and points.end_s == pytest.approx(0.2)
    assert points.bag_start_s == pytest.approx(T0_NS * 1e-9)
    assert topics["/scan"].count == 2 and topics["/cam/info"].count == 1
    assert topics["/chatter"].supported is False and points.supported
    assert topics["/scan"].to_dict()["msgtype"] == "sensor_msgs/msg/LaserScan"


def test_single_mcap_file(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "b", StoragePlugin.MCAP)
    (mcap,) = bag.glob("*.mcap")
    assert {t.name: t.count for t in list_topics(mcap)}["/lidar/points"] == 3
    samples, _ = read_all({"path": str(mcap), "topic": "/cam/mono"})
    np.testing.assert_array_equal(samples[0].image, MONO)


# --- bad input --------------------------------------------------------------------------------


def test_missing_topic_lists_available_topics(bag: Path) -> None:
    device = RosbagSource(str(bag), "/camera/image_raw")
    with pytest.raises(RosbagError) as info:
        device.open()
    err = info.value
    assert isinstance(err, InputError) and isinstance(err, DeviceError)
    assert err.input == str(bag) and str(bag) in err.message and "/camera/image_raw" in err.message
    assert "/lidar/points (sensor_msgs/msg/PointCloud2)" in err.message
    assert "/scan (sensor_msgs/msg/LaserScan)" in err.message
    with pytest.raises(DeviceError, match="not open"):
        device.read()


def test_unsupported_type_is_named(bag: Path) -> None:
    with pytest.raises(RosbagError, match="std_msgs/msg/String"):
        RosbagSource(str(bag), "/chatter").open()


@pytest.mark.parametrize("storage", [StoragePlugin.SQLITE3, StoragePlugin.MCAP], ids=["sqlite3", "mcap"])
def test_truncated_bag_names_the_file(tmp_path: Path, storage: StoragePlugin) -> None:
    bag = write_bag(tmp_path / "cut", storage)
    (storage_file,) = [p for p in bag.iterdir() if p.suffix in (".db3", ".mcap")]
    data = storage_file.read_bytes()
    storage_file.write_bytes(data[: len(data) // 2])
    for path in (bag, storage_file):
        with pytest.raises(InputError) as info:
            list_topics(path)
        assert info.value.input == str(path) and str(path) in info.value.message
        with pytest.raises(InputError) as info:
            read_all({"path": str(path), "topic": "/lidar/points"})
        assert info.value.input == str(path)


def test_unknown_and_missing_files(tmp_path: Path) -> None:
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    garbage = tmp_path / "fake.mcap"
    garbage.write_bytes(b"\x00" * 100)
    for path, words in [(text, "unknown file"), (garbage, "corrupt"), (tmp_path / "nope", "does not exist"),
                        (tmp_path, "not a ROS 2 bag")]:
        with pytest.raises(InputError, match=words) as info:
            RosbagSource(str(path), "/scan").open()
        assert info.value.input == str(path)
    with pytest.raises(DeviceError, match="bad settings"):
        create_device({"driver": "rosbag", "path": str(text)})  # no topic


def test_damage_found_mid_replay_ends_it_with_an_error_naming_the_bag(bag: Path) -> None:
    device = RosbagSource(str(bag), "/lidar/points")
    device.open()
    device.read()

    def damaged():
        raise ValueError("chunk CRC mismatch")
        yield  # pragma: no cover

    device._messages = damaged()  # what the storage layer does on a chunk it cannot read
    with pytest.raises(InputError) as info:
        device.read()
    assert info.value.input == str(bag) and "chunk CRC mismatch" in info.value.message
    with pytest.raises(DeviceDisconnected, match="after 1 messages"):
        device.read()
    device.close()
    device.close()
