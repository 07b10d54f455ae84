"""Livox ``.lvx`` (LVX 1.1) recordings, written here byte by byte as Livox-SDK's ``lvx_file.cpp`` writes them:
replayed through the ``lvx`` driver, accumulated over a window, read as a cloud file, their IMU read as samples."""

from __future__ import annotations

import calendar
import json
import struct
from pathlib import Path

import numpy as np
import pytest

from backend.core.errors import InputError
from backend.devices.base import DeviceDisconnected, DeviceError, Sample, create_device
from backend.devices.cloud_files import read_cloud
from backend.devices.lvx_file import LvxError, read_lvx_cloud, read_lvx_imu
from tests.conftest import cli_in_process

RNG = np.random.default_rng(6)
HORIZON = 3
"""Livox SDK 1 device type of the Horizon: a point every 4167 ns."""
INTERVAL_NS = 4167
T0_NS = 5_000_000_000
"""The first package's time stamp (ns since the LiDAR's power-on: no time sync)."""
FRAME_NS = 50_000_000
FRAMES = 12
IMU_PER_FRAME = 10
"""200 Hz."""
G = 9.80665


def package(device: int, data_type: int, stamp: int, records: bytes, timestamp_type: int = 0,
            version: int = 5) -> bytes:
    return struct.pack("<5BIBBQ", device, version, 1, 1, 0, 0, timestamp_type, data_type, stamp) + records


def single_records(xyz_mm: np.ndarray, reflectivity: np.ndarray) -> bytes:
    return b"".join(struct.pack("<3iBB", *map(int, p), int(r), 0) for p, r in zip(xyz_mm, reflectivity, strict=True))


def dual_records(xyz_mm: np.ndarray, reflectivity: np.ndarray) -> bytes:
    """``xyz_mm`` (48, 2, 3): the two returns of each firing."""
    return b"".join(struct.pack("<3iBB3iBB", *map(int, p[0]), int(r[0]), 0, *map(int, p[1]), int(r[1]), 0)
                    for p, r in zip(xyz_mm, reflectivity, strict=True))


def lvx_file(path: Path, frames: list[list[bytes]], devices: tuple[int, ...] = (0,), version=(1, 1, 0, 0)) -> Path:
    head = struct.pack("<16s4BIIB", b"livox_tech", *version, 0xAC0EA767, 50, len(devices))
    for index in devices:
        head += struct.pack("<16s16sBBB6f", f"3WEDH7600{index}0123".encode(), b"", index, HORIZON, 0, *[0.0] * 6)
    body, offset = b"", len(head)
    for k, packages in enumerate(frames):
        size = 24 + sum(map(len, packages))
        body += struct.pack("<3Q", offset, offset + size, k) + b"".join(packages)
        offset += size
    path.write_bytes(head + body)
    return path


class Truth:
    """What the recording holds, per frame: points (m), reflectivity, times (ns); and the IMU's samples."""

    def __init__(self) -> None:
        self.points, self.reflectivity, self.time_ns, self.frames = [], [], [], []
        self.imu_t_ns, self.gyro, self.accel_g = [], [], []
        for k in range(FRAMES):
            packages, points, refl, times = [], [], [], []
            for j in range(2):  # two single-return packages of 96 points
                stamp = T0_NS + k * FRAME_NS + j * 96 * INTERVAL_NS
                xyz = RNG.integers(-30_000, 30_000, (96, 3))
                xyz[7 * j + 3] = 0  # no return
                r = RNG.integers(0, 256, 96)
                packages.append(package(0, 2, stamp, single_records(xyz, r)))
                keep = xyz.any(axis=1)
                points.append(xyz[keep] * 1e-3)
                refl.append(r[keep])
                times.append(stamp + np.arange(96)[keep] * INTERVAL_NS)
            stamp = T0_NS + k * FRAME_NS + 192 * INTERVAL_NS  # then one dual-return package of 48 pairs
            xyz = RNG.integers(-30_000, 30_000, (48, 2, 3))
            r = RNG.integers(0, 256, (48, 2))
            packages.append(package(0, 4, stamp, dual_records(xyz, r)))
            points.append(xyz.reshape(-1, 3) * 1e-3)
            refl.append(r.ravel())
            times.append(stamp + np.repeat(np.arange(48), 2) * INTERVAL_NS)
            for i in range(IMU_PER_FRAME):
                t = T0_NS + k * FRAME_NS + i * 5_000_000 + 1000
                gyro, accel = RNG.normal(0, 0.3, 3).astype(np.float32), (RNG.normal(0, 0.1, 3) + [0, 0, 1]).astype(
                    np.float32)
                packages.append(package(0, 6, t, struct.pack("<6f", *gyro, *accel)))
                self.imu_t_ns.append(t)
                self.gyro.append(gyro)
                self.accel_g.append(accel)
            self.frames.append(packages)
            self.points.append(np.concatenate(points))
            self.reflectivity.append(np.concatenate(refl))
            self.time_ns.append(np.concatenate(times))


TRUTH = Truth()


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return lvx_file(tmp_path_factory.mktemp("lvx") / "horizon.lvx", TRUTH.frames)


def replay(settings: dict) -> list[Sample]:
    samples = []
    with create_device({"driver": "lvx", **settings}) as device:
        while True:
            try:
                samples.append(device.read())
            except DeviceDisconnected:
                return samples


def test_frames_replay_points_reflectivity_and_point_times(recording: Path) -> None:
    samples = replay({"path": str(recording)})
    assert len(samples) == FRAMES
    for k, sample in enumerate(samples):
        np.testing.assert_array_equal(sample.points, TRUTH.points[k])  # mm to m, both returns of each pair
        assert sample.intensity.dtype == np.float32
        np.testing.assert_array_equal(sample.intensity, TRUTH.reflectivity[k])
        assert sample.timestamp_s == TRUTH.time_ns[k][0] * 1e-9
        np.testing.assert_array_equal(np.round(sample.meta["point_time_s"] * 1e9),
                                      TRUTH.time_ns[k] - TRUTH.time_ns[k][0])
        assert sample.meta["data_types"] == [2, 4] and sample.meta["model"] == "Horizon"
        assert sample.meta["frame_index"] == k
        imu = sample.imu
        np.testing.assert_array_equal(np.round(imu.t_s * 1e9), TRUTH.imu_t_ns[k * 10:(k + 1) * 10])
        np.testing.assert_array_equal(imu.gyro_rad_s, np.array(TRUTH.gyro[k * 10:(k + 1) * 10], np.float64))
        np.testing.assert_allclose(imu.accel_m_s2, np.array(TRUTH.accel_g[k * 10:(k + 1) * 10], np.float64) * G,
                                   rtol=1e-15)


def test_a_window_of_the_recording_accumulates_into_one_cloud(recording: Path) -> None:
    whole = read_lvx_cloud(recording)
    np.testing.assert_array_equal(whole.points, np.concatenate(TRUTH.points))
    assert whole.frames == FRAMES and whole.device.model == "Horizon"
    assert whole.device.broadcast_code == "3WEDH760000123"
    window = read_lvx_cloud(recording, start_s=0.1, end_s=0.2)
    times = np.concatenate(TRUTH.time_ns) - T0_NS
    inside = (times >= 100_000_000) & (times <= 200_000_000)
    np.testing.assert_array_equal(window.points, np.concatenate(TRUTH.points)[inside])
    np.testing.assert_array_equal(window.reflectivity, np.concatenate(TRUTH.reflectivity)[inside])
    np.testing.assert_allclose(window.time_s, times[inside] * 1e-9, rtol=0, atol=1e-12)
    with pytest.raises(LvxError, match="no points of device 0 .Horizon. from 5 s to 6 s"):
        read_lvx_cloud(recording, start_s=5.0, end_s=6.0)


def test_read_cloud_reads_a_whole_lvx(recording: Path) -> None:
    cloud = read_cloud(recording)
    np.testing.assert_array_equal(cloud.points, np.concatenate(TRUTH.points))
    np.testing.assert_array_equal(cloud.intensity, np.concatenate(TRUTH.reflectivity))
    assert cloud.fields == ["x", "y", "z", "reflectivity"] and cloud.dropped_non_finite == 0


def test_the_builtin_imu_reads_as_checked_samples(recording: Path) -> None:
    samples, warnings = read_lvx_imu(recording)
    assert warnings == [] and len(samples.t_s) == FRAMES * IMU_PER_FRAME
    np.testing.assert_array_equal(np.round(samples.t_s * 1e9), TRUTH.imu_t_ns)
    np.testing.assert_array_equal(samples.gyro_rad_s, np.array(TRUTH.gyro, np.float64))
    assert samples.rate_hz == pytest.approx(200, rel=1e-6)


def test_the_imu_commands_read_a_recordings_builtin_imu(tmp_path: Path) -> None:
    """``lidar-imu --imu recording.lvx``: one frame holds 10 IMU samples, and the refusal names the recording."""
    path = lvx_file(tmp_path / "short.lvx", TRUTH.frames[:1])
    run = cli_in_process("lidar-imu", "--scans", tmp_path, "--imu", path, "--json")
    assert run.returncode == 2, run.stderr
    error = json.loads(run.stdout)["error"]
    assert error["input"] == str(path) and "(device 0) holds 10 IMU sample(s); at least 100" in error["message"]


def test_several_devices_need_one_chosen(tmp_path: Path) -> None:
    xyz = RNG.integers(1, 30_000, (96, 3))
    frames = [[package(0, 2, T0_NS, single_records(xyz, np.full(96, 9))),
               package(1, 2, T0_NS, single_records(-xyz, np.full(96, 200)))]]
    path = lvx_file(tmp_path / "hub.lvx", frames, devices=(0, 1))
    with pytest.raises(DeviceError, match=r"holds 2 devices: choose one with device_index \(0 \(Horizon 3WEDH76000"):
        replay({"path": str(path)})
    (sample,) = replay({"path": str(path), "device_index": 1})
    np.testing.assert_array_equal(sample.points, -xyz * 1e-3)
    assert (sample.intensity == 200).all() and sample.imu is None
    with pytest.raises(LvxError, match="has no device 4; its devices: 0 .Horizon"):
        read_lvx_cloud(path, device_index=4)


def test_pps_gps_time_stamps_are_utc(tmp_path: Path) -> None:
    """PPS+GPS (type 3): year - 2000, month, day, hour in the first 4 bytes, microseconds in the hour after."""
    stamp = int.from_bytes(bytes([24, 5, 17, 13]) + (1_234_567).to_bytes(4, "little"), "little")
    xyz = RNG.integers(1, 30_000, (96, 3))
    path = lvx_file(tmp_path / "gps.lvx", [[package(0, 2, stamp, single_records(xyz, np.ones(96)), timestamp_type=3)]])
    (sample,) = replay({"path": str(path)})
    expected_ns = calendar.timegm((2024, 5, 17, 13, 0, 0)) * 10**9 + 1_234_567_000
    assert round(sample.timestamp_s * 1e6) == expected_ns // 1000
    assert round(sample.meta["point_time_s"][-1] * 1e9) == 95 * INTERVAL_NS


# --- bad input --------------------------------------------------------------------------------


def one_line(exc: pytest.ExceptionInfo, path: Path) -> str:
    assert isinstance(exc.value, InputError) and exc.value.input == str(path)
    assert "\n" not in exc.value.message and str(path) in exc.value.message
    return exc.value.message


def test_a_truncated_recording_names_the_file_and_frame(recording: Path, tmp_path: Path) -> None:
    cut = tmp_path / "cut.lvx"
    data = recording.read_bytes()
    cut.write_bytes(data[: len(data) - 500])
    with pytest.raises(LvxError) as info:
        read_cloud(cut)
    message = one_line(info, cut)
    assert f"frame {FRAMES - 1} at byte" in message and "is truncated: it should end at byte" in message
    samples: list[Sample] = []
    with create_device({"driver": "lvx", "path": str(cut)}) as device:
        with pytest.raises(LvxError, match="truncated"):
            while True:
                samples.append(device.read())
        assert len(samples) == FRAMES - 1
        with pytest.raises(DeviceDisconnected, match=f"after {FRAMES - 1} frames"):
            device.read()
    cut.write_bytes(data[:30])
    with pytest.raises(LvxError, match="truncated in its header"):
        read_lvx_cloud(cut)


@pytest.mark.parametrize(("version", "words"), [((1, 0, 0, 0), "LVX version 1.0.0.0; expected 1.1.0.0"),
                                                ((2, 0, 0, 0), "LVX version 2.0.0.0 .LVX 2, written for the Mid-360")])
def test_an_unknown_version_is_named(tmp_path: Path, version: tuple, words: str) -> None:
    path = lvx_file(tmp_path / "v.lvx", TRUTH.frames[:1], version=version)
    with pytest.raises(LvxError, match=words) as info:
        create_device({"driver": "lvx", "path": str(path)}).open()
    one_line(info, path)


def test_unknown_data_types_protocol_versions_and_other_files_are_named(tmp_path: Path) -> None:
    spherical = package(0, 1, T0_NS, b"\0" * 9 * 100)
    path = lvx_file(tmp_path / "mid40.lvx", [[spherical]])
    with pytest.raises(LvxError, match=r"frame 0 at byte \d+: a data packet has data type 1 .spherical., which is "
                                       r"not read; expected 2 .extended Cartesian.") as info:
        read_lvx_cloud(path)
    one_line(info, path)
    path = lvx_file(tmp_path / "sdk2.lvx", [[package(0, 2, T0_NS, b"\0" * 14 * 96, version=6)]])
    with pytest.raises(LvxError, match="protocol version 6; expected 5 .Livox SDK 1."):
        read_lvx_cloud(path)
    text = tmp_path / "notes.lvx"
    text.write_text("hello, not a recording")
    with pytest.raises(LvxError, match="not an LVX file") as info:
        read_cloud(text)
    one_line(info, text)
