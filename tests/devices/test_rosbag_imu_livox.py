"""sensor_msgs/Imu and Livox CustomMsg topics from ROS 1 and ROS 2 bags (written here with rosbags' writers), and
``calib-studio camera-imu --imu BAG --imu-topic`` against the same samples given as a CSV file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import get_types_from_msg

from backend.devices.base import DeviceDisconnected, Sample, create_device
from backend.devices.imu_csv import format_imu_csv, read_imu_csv
from backend.devices.rosbag_source import (
    LIVOX_CUSTOM_MSG,
    LIVOX_CUSTOM_MSGS,
    LIVOX_CUSTOM_POINT,
    RosbagError,
    list_topics,
    read_imu_topic,
    typestore,
)
from backend.exports.ros_camera_info import write_camera_info
from backend.sim.camera_imu import BOARD, recording_files, simulate_recording
from tests.conftest import cli_in_process

T0_NS = 1_700_000_000 * 10**9
"""Receive time of the first message in every test bag."""
IMU_PERIOD_NS = 5_000_000
"""200 Hz."""
RNG = np.random.default_rng(23)
IMU_N = 300
IMU_GYRO = RNG.normal(0, 0.5, (IMU_N, 3))
IMU_ACCEL = RNG.normal(0, 2, (IMU_N, 3)) + [0, 0, 9.81]
LIVOX_TOPICS = {"/livox/ros1": LIVOX_CUSTOM_MSGS[0], "/livox/ros2": LIVOX_CUSTOM_MSGS[1],
                "/livox/interfaces": LIVOX_CUSTOM_MSGS[2]}
SCAN_N = 40
SCAN_XYZ = [RNG.uniform(-30, 30, (SCAN_N, 3)).astype(np.float32) for _ in range(2)]
SCAN_REFLECTIVITY = [RNG.integers(0, 256, SCAN_N).astype(np.uint8) for _ in range(2)]
SCAN_OFFSET_NS = [np.sort(RNG.integers(0, 100_000_000, SCAN_N)).astype(np.uint32) for _ in range(2)]
for _xyz in SCAN_XYZ:
    _xyz[5] = 0.0  # Livox's "no return"
    _xyz[9, 0] = np.nan
SCAN_KEEP = np.setdiff1d(np.arange(SCAN_N), [5, 9])


def header(ts, t_ns: int, frame: str):
    stamp = ts.types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
    if "seq" in [name for name, _ in ts.fielddefs["std_msgs/msg/Header"][1]]:  # ROS 1
        return ts.types["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
    return ts.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def imu_msg(ts, t_ns: int, gyro: np.ndarray, accel: np.ndarray, gyro_covariance: float = 0.0):
    vector, T = ts.types["geometry_msgs/msg/Vector3"], ts.types
    return T["sensor_msgs/msg/Imu"](
        header=header(ts, t_ns, "imu"), orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.full(9, -1.0), angular_velocity=vector(x=gyro[0], y=gyro[1], z=gyro[2]),
        angular_velocity_covariance=np.full(9, gyro_covariance), linear_acceleration=vector(
            x=accel[0], y=accel[1], z=accel[2]), linear_acceleration_covariance=np.zeros(9))


def imu_msgs(ts, stamps_ns: list[int], gyro: np.ndarray = IMU_GYRO, accel: np.ndarray = IMU_ACCEL,
             gyro_covariance: float = 0.0) -> list:
    return [imu_msg(ts, t, g, a, gyro_covariance) for t, g, a in zip(stamps_ns, gyro, accel, strict=True)]


def custom_msg(ts, msgtype: str, k: int):
    package = msgtype.split("/")[0]
    point = ts.types[f"{package}/msg/CustomPoint"]
    timebase = T0_NS + k * 100_000_000
    points = [point(offset_time=int(o), x=float(x), y=float(y), z=float(z), reflectivity=int(r), tag=0x10,
                    line=i % 6)
              for i, (o, (x, y, z), r) in enumerate(zip(SCAN_OFFSET_NS[k], SCAN_XYZ[k], SCAN_REFLECTIVITY[k],
                                                        strict=True))]
    return ts.types[msgtype](header=header(ts, timebase + 1_000_000, "livox_frame"), timebase=timebase,
                             point_num=SCAN_N, lidar_id=3, rsvd=np.zeros(3, np.uint8), points=points)


def write_bag(path: Path, topics: dict[str, tuple[str, list]], ros1: bool, stamps_ns: dict[str, list[int]],
              storage: StoragePlugin = StoragePlugin.MCAP, ts=None) -> Path:
    """``topics``: name -> (type, messages), each message received at its ``stamps_ns``."""
    ts = ts or typestore(ros1)
    with (Writer1(path) if ros1 else Writer2(path, version=9, storage_plugin=storage)) as writer:
        for topic, (msgtype, msgs) in topics.items():
            connection = writer.add_connection(topic, msgtype, typestore=ts)
            for t_ns, msg in zip(stamps_ns[topic], msgs, strict=True):
                raw = ts.serialize_ros1(msg, msgtype) if ros1 else ts.serialize_cdr(msg, msgtype)
                writer.write(connection, t_ns, raw)
    return path


def imu_stamps(n: int = IMU_N) -> list[int]:
    return [T0_NS + i * IMU_PERIOD_NS for i in range(n)]


BAG_KINDS = {"ros1": (True, StoragePlugin.MCAP), "ros2-mcap": (False, StoragePlugin.MCAP),
             "ros2-sqlite3": (False, StoragePlugin.SQLITE3)}


@pytest.fixture(scope="module", params=list(BAG_KINDS))
def bag(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An IMU topic and one CustomMsg topic of each Livox package."""
    ros1, storage = BAG_KINDS[request.param]
    ts = typestore(ros1)
    topics = {"/imu0": ("sensor_msgs/msg/Imu", imu_msgs(ts, imu_stamps()))}
    stamps = {"/imu0": imu_stamps()}
    for topic, msgtype in LIVOX_TOPICS.items():
        topics[topic] = (msgtype, [custom_msg(ts, msgtype, k) for k in range(2)])
        stamps[topic] = [T0_NS + k * 100_000_000 + 2_000_000 for k in range(2)]
    folder = tmp_path_factory.mktemp(request.param)
    return write_bag(folder / ("rig.bag" if ros1 else "rig"), topics, ros1, stamps, storage)


def read_all(settings: dict) -> list[Sample]:
    samples = []
    with create_device({"driver": "rosbag", **settings}) as device:
        while True:
            try:
                samples.append(device.read())
            except DeviceDisconnected:
                return samples


# --- IMU ---------------------------------------------------------------------------------------


def test_imu_topic_reads_back_what_was_written(bag: Path) -> None:
    samples, warnings = read_imu_topic(bag, "/imu0")
    assert warnings == []
    np.testing.assert_array_equal(samples.gyro_rad_s, IMU_GYRO)  # float64 in the message: exact
    np.testing.assert_array_equal(samples.accel_m_s2, IMU_ACCEL)
    np.testing.assert_allclose(samples.t_s, np.array(imu_stamps()) * 1e-9, rtol=0, atol=1e-6)  # float64 at 1.7e9 s
    assert {t.name: t.supported for t in list_topics(bag)} == {"/imu0": True, **dict.fromkeys(LIVOX_TOPICS, True)}


def test_imu_replays_one_sample_per_read(bag: Path) -> None:
    samples = read_all({"path": str(bag), "topic": "/imu0", "end_s": 0.012})
    assert len(samples) == 3
    for i, sample in enumerate(samples):
        assert sample.points is None and len(sample.imu.t_s) == 1
        assert sample.imu.t_s[0] == sample.timestamp_s == pytest.approx((T0_NS + i * IMU_PERIOD_NS) * 1e-9, abs=1e-6)
        np.testing.assert_array_equal(sample.imu.gyro_rad_s[0], IMU_GYRO[i])
        np.testing.assert_array_equal(sample.imu.accel_m_s2[0], IMU_ACCEL[i])


def test_a_missing_imu_topic_lists_the_bags_imu_topics(bag: Path) -> None:
    with pytest.raises(RosbagError) as info:
        read_imu_topic(bag, "/imu")
    assert info.value.input == str(bag)
    assert "no IMU topic '/imu'" in info.value.message and "sensor_msgs/msg/Imu topics: /imu0" in info.value.message
    with pytest.raises(RosbagError, match="/livox/ros1.*not sensor_msgs/msg/Imu.*topics: /imu0"):
        read_imu_topic(bag, "/livox/ros1")


def test_time_stamps_running_backwards_name_the_bag_topic_and_time(tmp_path: Path) -> None:
    ts = typestore(True)
    stamps = imu_stamps()
    stamps[150] = stamps[148]  # back by two periods
    msgs = imu_msgs(ts, stamps)
    bag = write_bag(tmp_path / "back.bag", {"/imu0": ("sensor_msgs/msg/Imu", msgs)}, True, {"/imu0": imu_stamps()})
    with pytest.raises(RosbagError) as info:
        read_imu_topic(bag, "/imu0")
    message = info.value.message
    assert info.value.input == str(bag) and f"bag {bag} topic /imu0" in message and "\n" not in message
    assert "run backwards or repeat at sample 151" in message
    assert f"{stamps[148] * 1e-9:.6f} s after {stamps[149] * 1e-9:.6f} s" in message


def test_gaps_are_warned_naming_the_bag_topic_and_where(tmp_path: Path) -> None:
    ts = typestore(False)
    stamps = imu_stamps()
    stamps[201:] = [t + 500_000_000 for t in stamps[201:]]  # 0.5 s lost after 1 s
    msgs = imu_msgs(ts, stamps)
    bag = write_bag(tmp_path / "gap", {"/imu0": ("sensor_msgs/msg/Imu", msgs)}, False, {"/imu0": stamps})
    samples, (warning,) = read_imu_topic(bag, "/imu0")
    assert len(samples.t_s) == IMU_N
    assert warning.startswith(f"bag {bag} topic /imu0: 1 gap(s)") and "505 ms at 1.00 s" in warning


def test_an_imu_that_does_not_measure_rates_is_refused(tmp_path: Path) -> None:
    ts = typestore(False)
    msgs = imu_msgs(ts, imu_stamps(), gyro_covariance=-1.0)
    bag = write_bag(tmp_path / "orientation_only", {"/imu0": ("sensor_msgs/msg/Imu", msgs)}, False,
                    {"/imu0": imu_stamps()})
    with pytest.raises(RosbagError, match=r"topic /imu0 at stamp 1700000000.000000 s: the IMU does not report its "
                                          r"angular_velocity"):
        read_imu_topic(bag, "/imu0")


def test_a_truncated_ros1_bag_names_the_file(tmp_path: Path) -> None:
    ts = typestore(True)
    bag = write_bag(tmp_path / "cut.bag", {"/imu0": ("sensor_msgs/msg/Imu", imu_msgs(ts, imu_stamps()))}, True,
                    {"/imu0": imu_stamps()})
    bag.write_bytes(bag.read_bytes()[:5000])
    with pytest.raises(RosbagError, match="truncated or corrupt") as info:
        read_imu_topic(bag, "/imu0")
    assert info.value.input == str(bag) and str(bag) in info.value.message


# --- Livox CustomMsg ----------------------------------------------------------------------------


@pytest.mark.parametrize("topic", list(LIVOX_TOPICS))
def test_custom_msg_points_reflectivity_and_point_times(bag: Path, topic: str) -> None:
    samples = read_all({"path": str(bag), "topic": topic})
    assert len(samples) == 2
    for k, sample in enumerate(samples):
        np.testing.assert_array_equal(sample.points, SCAN_XYZ[k][SCAN_KEEP].astype(np.float64))
        assert sample.intensity.dtype == np.float32
        np.testing.assert_array_equal(sample.intensity, SCAN_REFLECTIVITY[k][SCAN_KEEP])
        np.testing.assert_array_equal(np.round(sample.meta["point_time_s"] * 1e9), SCAN_OFFSET_NS[k][SCAN_KEEP])
        assert sample.timestamp_s == (T0_NS + k * 100_000_000) * 1e-9  # the time base, not the header stamp
        assert sample.meta["lidar_id"] == 3 and sample.meta["msgtype"] == LIVOX_TOPICS[topic]
        assert sample.meta["frame_id"] == "livox_frame"


def test_an_unknown_custom_msg_like_type_is_named(tmp_path: Path) -> None:
    ts = typestore(False)
    ts.register(get_types_from_msg(LIVOX_CUSTOM_POINT, "acme_lidar/msg/CustomPoint")
                | get_types_from_msg(LIVOX_CUSTOM_MSG, "acme_lidar/msg/CustomMsg"))
    msg = ts.types["acme_lidar/msg/CustomMsg"](header=header(ts, T0_NS, "l"), timebase=T0_NS, point_num=0, lidar_id=0,
                                               rsvd=np.zeros(3, np.uint8), points=[])
    bag = write_bag(tmp_path / "acme", {"/acme": ("acme_lidar/msg/CustomMsg", [msg])}, False, {"/acme": [T0_NS]},
                    ts=ts)
    with pytest.raises(RosbagError) as info:
        create_device({"driver": "rosbag", "path": str(bag), "topic": "/acme"}).open()
    message = info.value.message
    assert "\n" not in message and "'/acme'" in message
    assert "acme_lidar/msg/CustomMsg, which cannot be replayed" in message
    assert all(msgtype in message for msgtype in LIVOX_CUSTOM_MSGS)


# --- the command --------------------------------------------------------------------------------


@pytest.mark.slow
def test_camera_imu_reads_the_imu_from_a_bag_as_from_its_csv(tmp_path: Path) -> None:
    """The same samples from a CSV file and from a ROS 1 bag's topic give the same JSON, T_cam_imu within 1e-9."""
    recording = simulate_recording(duration_s=6.0)
    imu_csv, detections_csv = recording_files(recording)
    (tmp_path / "imu.csv").write_bytes(imu_csv)
    (tmp_path / "detections.csv").write_bytes(detections_csv)
    write_camera_info(tmp_path / "camera.yaml", recording.camera, "cam0")
    samples, _ = read_imu_csv(tmp_path / "imu.csv")
    ts = typestore(True)
    stamps = [round(t * 1e9) for t in samples.t_s]
    msgs = imu_msgs(ts, stamps, samples.gyro_rad_s, samples.accel_m_s2)
    bag = write_bag(tmp_path / "rig.bag", {"/imu0": ("sensor_msgs/msg/Imu", msgs)}, True, {"/imu0": stamps})
    from_bag, _ = read_imu_topic(bag, "/imu0")
    np.testing.assert_array_equal(from_bag.gyro_rad_s, samples.gyro_rad_s)
    np.testing.assert_array_equal(from_bag.accel_m_s2, samples.accel_m_s2)
    np.testing.assert_allclose(from_bag.t_s, samples.t_s, rtol=0, atol=1e-12)
    assert format_imu_csv(from_bag) == imu_csv

    common = ("camera-imu", "--camera", tmp_path / "camera.yaml", "--detections", tmp_path / "detections.csv",
              "--board", BOARD, "--json")
    runs = [cli_in_process(*common, "--imu", tmp_path / "imu.csv"),
            cli_in_process(*common, "--imu", bag, "--imu-topic", "/imu0")]
    assert all(run.returncode == 0 for run in runs), [run.stderr for run in runs]
    csv_json, bag_json = (json.loads(run.stdout) for run in runs)
    assert set(bag_json) == set(csv_json)
    np.testing.assert_allclose(bag_json["T_cam_imu"], csv_json["T_cam_imu"], rtol=0, atol=1e-9)
    assert bag_json["time_offset_s"] == pytest.approx(csv_json["time_offset_s"], abs=1e-9)
    assert bag_json["verdict"] == csv_json["verdict"]


def test_the_command_names_the_imu_topics_it_needs(tmp_path: Path) -> None:
    ts = typestore(True)
    bag = write_bag(tmp_path / "rig.bag", {"/imu0": ("sensor_msgs/msg/Imu", imu_msgs(ts, imu_stamps()))}, True,
                    {"/imu0": imu_stamps()})
    common = ("--camera", tmp_path / "camera.yaml", "--detections", tmp_path / "d.csv", "--board", BOARD, "--json")
    run = cli_in_process("camera-imu", *common, "--imu", bag, "--imu-topic", "/imu")
    assert run.returncode == 2
    error = json.loads(run.stdout)["error"]
    assert error["input"] == str(bag) and "no IMU topic '/imu'" in error["message"]
    assert "sensor_msgs/msg/Imu topics: /imu0" in error["message"]
    run = cli_in_process("camera-imu", *common, "--imu", bag, "--imu-topic", "/imu0", "--imu-model", "size-effect")
    assert run.returncode == 2 and "invalid choice: 'size-effect'" in run.stderr  # Kalibr's other two only
    run = cli_in_process("lidar-imu", "--scans", tmp_path, "--imu", bag, "--json")
    assert run.returncode == 2 and "--imu-topic" in run.stderr and "topics: /imu0" in run.stderr
    (tmp_path / "imu.csv").write_text("#t_ns,wx,wy,wz,ax,ay,az\n")
    run = cli_in_process("lidar-imu", "--scans", tmp_path, "--imu", tmp_path / "imu.csv", "--imu-topic", "/imu0")
    assert run.returncode == 2 and "is not one" in run.stderr
