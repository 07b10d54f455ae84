"""Point-cloud file reading and the ``cloud_files`` driver: real OpenCalib clouds, round trips, bad input."""

from __future__ import annotations

import struct
from pathlib import Path

import laspy
import numpy as np
import pytest
from pypcd4 import Encoding, PointCloud

from backend.core.clouds import check_cloud
from backend.core.errors import InputError
from backend.devices.base import DeviceDisconnected, DeviceError, create_device
from backend.devices.cloud_files import CLOUD_EXTENSIONS, CloudFile, CloudFolder, read_cloud
from tests.conftest import SHARED_DATA

SHARED_DATA = SHARED_DATA
PAIR = SHARED_DATA / "opencalib_lidar2lidar_pair"
P64 = PAIR / "p64.pcd"
QT = PAIR / "qt.pcd"
CALIB = SHARED_DATA / "opencalib_lidar2camera" / "calib.pcd"


def require(path: Path) -> Path:
    if not path.is_file():
        pytest.fail(f"real data missing: {path} (shared/data must sit beside the checkout)")
    return path


def random_cloud(n: int = 500, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points (m) spread like a LiDAR scan, and intensities 0..255."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(-40.0, 40.0, size=(n, 3))
    points[:, 2] = rng.uniform(-2.0, 5.0, size=n)
    intensity = rng.integers(0, 256, size=n).astype(np.float32)
    return points, intensity


# --- real data -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("path", "count", "fields", "range_m"),
    [
        (P64, 77_547, ["x", "y", "z", "intensity", "ring", "timestamp"], (2.2, 130.0)),
        (QT, 12_414, ["x", "y", "z", "intensity", "t"], (0.5, 34.4)),
        (CALIB, 85_546, ["x", "y", "z", "intensity", "ring", "timestamp"], (2.5, 130.0)),
    ],
    ids=["p64", "qt", "calib"],
)
def test_real_pcd(path: Path, count: int, fields: list[str], range_m: tuple[float, float]) -> None:
    cloud = read_cloud(require(path))
    assert isinstance(cloud, CloudFile)
    assert cloud.dropped_non_finite == 0  # checked: these files hold no NaN/inf points
    assert cloud.points.shape == (count, 3) and cloud.points.dtype == np.float64
    assert cloud.intensity is not None and cloud.intensity.shape == (count,) and cloud.intensity.dtype == np.float32
    assert 0.0 <= cloud.intensity.min() and cloud.intensity.max() <= 255.0 and cloud.intensity.max() > 50.0
    assert cloud.fields == fields
    assert cloud.source == str(path)
    ranges = np.linalg.norm(cloud.points, axis=1)
    assert range_m[0] - 0.1 <= ranges.min() < range_m[0] + 0.1
    assert range_m[1] - 1.0 < ranges.max() <= range_m[1] + 0.1
    check_cloud(cloud.points, path.name)  # metres: taken as they are


def test_real_cloud_in_millimetres_is_refused_by_name() -> None:
    cloud = read_cloud(require(QT))
    with pytest.raises(InputError, match="looks like millimetres, not metres .* scale by 0.001") as info:
        check_cloud(cloud.points * 1000.0, "qt.pcd")
    assert info.value.input == "qt.pcd"


# --- round trips ---------------------------------------------------------------------------------


@pytest.mark.parametrize("encoding", [Encoding.ASCII, Encoding.BINARY, Encoding.BINARY_COMPRESSED])
def test_pcd_round_trip(tmp_path: Path, encoding: Encoding) -> None:
    points, intensity = random_cloud()
    file = tmp_path / f"cloud_{encoding.value}.pcd"
    PointCloud.from_xyzi_points(np.column_stack([points, intensity])).save(file, encoding=encoding)
    cloud = read_cloud(file)
    np.testing.assert_allclose(cloud.points, points, atol=1e-5)  # float32 in the file
    np.testing.assert_array_equal(cloud.intensity, intensity)
    assert cloud.fields == ["x", "y", "z", "intensity"] and cloud.dropped_non_finite == 0


def test_pcd_without_intensity(tmp_path: Path) -> None:
    points, _ = random_cloud()
    file = tmp_path / "xyz.pcd"
    PointCloud.from_xyz_points(points).save(file, encoding=Encoding.BINARY)
    cloud = read_cloud(file)
    assert cloud.intensity is None and cloud.fields == ["x", "y", "z"]
    np.testing.assert_allclose(cloud.points, points, atol=1e-5)


@pytest.mark.slow
def test_ply_round_trip_open3d(tmp_path: Path) -> None:
    import open3d as o3d

    points, intensity = random_cloud()
    for ascii_ in (False, True):
        file = tmp_path / f"legacy_{ascii_}.ply"
        assert o3d.io.write_point_cloud(str(file), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)),
                                        write_ascii=ascii_)
        cloud = read_cloud(file)
        np.testing.assert_allclose(cloud.points, points, atol=1e-4 if ascii_ else 1e-9)  # ascii: 6 digits
        assert cloud.intensity is None
    tensor = o3d.t.geometry.PointCloud(o3d.core.Tensor(points.astype(np.float32)))
    tensor.point["intensity"] = o3d.core.Tensor(intensity[:, None])
    file = tmp_path / "with_intensity.ply"
    assert o3d.t.io.write_point_cloud(str(file), tensor)
    cloud = read_cloud(file)
    np.testing.assert_allclose(cloud.points, points, atol=1e-5)
    np.testing.assert_array_equal(cloud.intensity, intensity)
    assert cloud.fields == ["x", "y", "z", "intensity"]


def test_ply_mesh_and_big_endian(tmp_path: Path) -> None:
    """Vertex then face (list) elements, and a big-endian file, both read by the numpy reader."""
    points, _ = random_cloud(20)
    header = "ply\nformat binary_big_endian 1.0\nelement vertex 20\nproperty float x\nproperty float y\n" \
             "property float z\nproperty uchar intensity\nelement face 1\nproperty list uchar int vertex_indices\n" \
             "end_header\n"
    body = b"".join(struct.pack(">fffB", *p, i) for i, p in enumerate(points))
    file = tmp_path / "mesh_be.ply"
    file.write_bytes(header.encode() + body + struct.pack(">Biii", 3, 0, 1, 2))
    cloud = read_cloud(file)
    np.testing.assert_allclose(cloud.points, points, atol=1e-5)
    np.testing.assert_array_equal(cloud.intensity, np.arange(20, dtype=np.float32))


def test_ply_list_element_first_falls_back_to_open3d(tmp_path: Path) -> None:
    points, _ = random_cloud(10)
    header = "ply\nformat binary_little_endian 1.0\nelement face 1\nproperty list uchar int vertex_indices\n" \
             "element vertex 10\nproperty double x\nproperty double y\nproperty double z\nend_header\n"
    file = tmp_path / "face_first.ply"
    file.write_bytes(header.encode() + struct.pack("<Biii", 3, 0, 1, 2) + points.astype("<f8").tobytes())
    cloud = read_cloud(file)
    np.testing.assert_allclose(cloud.points, points, atol=1e-9)


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_las_round_trip(tmp_path: Path, suffix: str) -> None:
    points, intensity = random_cloud()
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.zeros(3)
    las = laspy.LasData(header)
    las.x, las.y, las.z = points[:, 0], points[:, 1], points[:, 2]
    las.intensity = intensity.astype(np.uint16)
    file = tmp_path / f"cloud{suffix}"
    las.write(file)
    cloud = read_cloud(file)
    np.testing.assert_allclose(cloud.points, points, atol=0.0005 + 1e-9)  # half the LAS scale
    np.testing.assert_array_equal(cloud.intensity, intensity)
    assert cloud.fields[:3] == ["x", "y", "z"] and "intensity" in cloud.fields


def test_npy_round_trip(tmp_path: Path) -> None:
    points, intensity = random_cloud()
    np.save(tmp_path / "xyz.npy", points)
    np.save(tmp_path / "xyzi.npy", np.column_stack([points, intensity]).astype(np.float32))
    xyz = read_cloud(tmp_path / "xyz.npy")
    np.testing.assert_array_equal(xyz.points, points)
    assert xyz.intensity is None and xyz.fields == ["x", "y", "z"]
    xyzi = read_cloud(tmp_path / "xyzi.npy")
    np.testing.assert_allclose(xyzi.points, points, atol=1e-5)
    np.testing.assert_array_equal(xyzi.intensity, intensity)
    assert xyzi.fields == ["x", "y", "z", "intensity"]


def test_npy_structured(tmp_path: Path) -> None:
    points, intensity = random_cloud(30)
    array = np.zeros(30, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("intensity", "u1")])
    array["x"], array["y"], array["z"], array["intensity"] = points.T[0], points.T[1], points.T[2], intensity
    np.save(tmp_path / "structured.npy", array)
    cloud = read_cloud(tmp_path / "structured.npy")
    np.testing.assert_allclose(cloud.points, points, atol=1e-5)
    np.testing.assert_array_equal(cloud.intensity, intensity)


# --- non-finite and empty clouds ---------------------------------------------------------------


def test_non_finite_points_dropped_and_counted(tmp_path: Path) -> None:
    points, intensity = random_cloud(100)
    points[[3, 10, 50], [0, 1, 2]] = [np.nan, np.inf, -np.inf]
    np.save(tmp_path / "bad.npy", np.column_stack([points, intensity]))
    PointCloud.from_xyzi_points(np.column_stack([points, intensity])).save(tmp_path / "bad.pcd",
                                                                           encoding=Encoding.ASCII)
    for name in ("bad.npy", "bad.pcd"):
        cloud = read_cloud(tmp_path / name)
        assert cloud.dropped_non_finite == 3
        keep = np.ones(100, bool)
        keep[[3, 10, 50]] = False
        np.testing.assert_allclose(cloud.points, points[keep], atol=1e-5)
        np.testing.assert_array_equal(cloud.intensity, intensity[keep])
        assert np.isfinite(cloud.points).all()


@pytest.mark.parametrize("kind", ["empty_npy", "empty_pcd", "all_nan_npy", "all_nan_pcd", "zero_bytes"])
def test_no_finite_points(tmp_path: Path, kind: str) -> None:
    if kind == "empty_npy":
        file = tmp_path / "empty.npy"
        np.save(file, np.zeros((0, 3)))
    elif kind == "empty_pcd":
        file = tmp_path / "empty.pcd"
        PointCloud.from_xyz_points(np.zeros((0, 3))).save(file, encoding=Encoding.ASCII)
    elif kind == "all_nan_npy":
        file = tmp_path / "nan.npy"
        np.save(file, np.full((10, 3), np.nan))
    elif kind == "all_nan_pcd":
        file = tmp_path / "nan.pcd"
        PointCloud.from_xyz_points(np.full((10, 3), np.nan)).save(file, encoding=Encoding.BINARY_COMPRESSED)
    else:
        file = tmp_path / "zero.pcd"
        file.write_bytes(b"")
    with pytest.raises(InputError) as info:
        read_cloud(file)
    assert info.value.input == str(file)
    assert file.name in info.value.message
    expected = "empty" if kind == "zero_bytes" else "holds no finite points"
    assert expected in info.value.message


# --- truncated, corrupt and unknown files --------------------------------------------------------


@pytest.mark.parametrize("source", [QT, P64], ids=["binary", "binary_compressed"])
def test_truncated_real_pcd(tmp_path: Path, source: Path) -> None:
    data = require(source).read_bytes()
    file = tmp_path / f"half_{source.name}"
    file.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError) as info:
        read_cloud(file)
    assert info.value.input == str(file) and file.name in info.value.message
    assert "truncated or corrupt" in info.value.message and "PCD" in info.value.message


def test_truncated_pcd_on_record_boundary(tmp_path: Path) -> None:
    """A binary PCD cut exactly between points still says it is short."""
    data = require(QT).read_bytes()
    body = data.index(b"DATA binary\n") + len(b"DATA binary\n")
    file = tmp_path / "cut.pcd"
    file.write_bytes(data[: body + 100 * 24])  # 100 whole points of 24 bytes (4 4 4 4 8)
    with pytest.raises(InputError, match="declares 12414 points, file holds 100"):
        read_cloud(file)


def test_truncated_ascii_pcd(tmp_path: Path) -> None:
    points, _ = random_cloud(100)
    file = tmp_path / "ascii.pcd"
    PointCloud.from_xyz_points(points).save(file, encoding=Encoding.ASCII)
    lines = file.read_text().splitlines(keepends=True)
    file.write_text("".join(lines[:-40]))
    with pytest.raises(InputError, match="ascii.pcd") as info:
        read_cloud(file)
    assert info.value.input == str(file)


def test_truncated_ply(tmp_path: Path) -> None:
    import open3d as o3d

    points, _ = random_cloud(100)
    file = tmp_path / "cut.ply"
    o3d.io.write_point_cloud(str(file), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)))
    data = file.read_bytes()
    file.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"cut\.ply: truncated or corrupt .*declares 100 vertices") as info:
        read_cloud(file)
    assert info.value.input == str(file)


@pytest.mark.parametrize("name", ["x.las", "x.laz", "x.pcd", "x.ply", "x.npy"])
def test_random_bytes(tmp_path: Path, name: str) -> None:
    file = tmp_path / name
    file.write_bytes(np.random.default_rng(7).bytes(2000))
    with pytest.raises(InputError) as info:
        read_cloud(file)
    assert info.value.input == str(file)
    assert info.value.message.startswith(f"{name}: truncated or corrupt file")
    assert "expected" in info.value.message


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_truncated_las(tmp_path: Path, suffix: str) -> None:
    points, _ = random_cloud(2000)
    las = laspy.LasData(laspy.LasHeader(point_format=0, version="1.2"))
    las.header.scales = np.array([0.001] * 3)
    las.x, las.y, las.z = points.T
    file = tmp_path / f"cut{suffix}"
    las.write(file)
    data = file.read_bytes()
    file.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=f"cut\\{suffix}: truncated or corrupt") as info:
        read_cloud(file)
    assert info.value.input == str(file)


def test_bad_npy_shapes_and_dtypes(tmp_path: Path) -> None:
    cases = {
        "two_columns.npy": np.zeros((10, 2)),
        "flat.npy": np.zeros(30),
        "strings.npy": np.array([["a", "b", "c"]]),
    }
    for name, array in cases.items():
        np.save(tmp_path / name, array)
    np.save(tmp_path / "objects.npy", np.array([[1, 2, 3], [None, 2, 3]], dtype=object), allow_pickle=True)
    for name, pattern in [("two_columns.npy", r"shape \(10, 2\); expected \(N, 3\)"), ("flat.npy", r"shape \(30,\)"),
                          ("strings.npy", "expected numbers"), ("objects.npy", "dtype object.*expected numbers")]:
        with pytest.raises(InputError, match=pattern) as info:
            read_cloud(tmp_path / name)
        assert info.value.input == str(tmp_path / name) and name in info.value.message


def test_unknown_extension_lists_formats(tmp_path: Path) -> None:
    file = tmp_path / "scan.xyz"
    file.write_text("1 2 3\n")
    with pytest.raises(InputError) as info:
        read_cloud(file)
    assert info.value.input == str(file) and "scan.xyz" in info.value.message
    for suffix in CLOUD_EXTENSIONS:
        assert suffix in info.value.message


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="nothere.pcd: does not exist") as info:
        read_cloud(tmp_path / "nothere.pcd")
    assert info.value.input == str(tmp_path / "nothere.pcd")


# --- the capture driver --------------------------------------------------------------------------


def write_recording(folder: Path) -> list[np.ndarray]:
    """scan1, scan2, scan3 (corrupt), scan10 as mixed formats, plus a non-cloud file."""
    folder.mkdir()
    clouds = [random_cloud(50 + i, seed=i)[0] for i in range(3)]
    np.save(folder / "scan1.npy", clouds[0])
    PointCloud.from_xyz_points(clouds[1]).save(folder / "scan2.pcd", encoding=Encoding.BINARY)
    (folder / "scan3.pcd").write_bytes(b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\n")
    with_nan = np.vstack([clouds[2], [[np.nan, 0.0, 0.0]]])
    np.save(folder / "scan10.npy", with_nan)
    (folder / "notes.txt").write_text("not a cloud")
    return clouds


def test_cloud_folder_driver(tmp_path: Path) -> None:
    clouds = write_recording(tmp_path / "rec")
    device = create_device({"driver": "cloud_files", "path": str(tmp_path / "rec")})
    assert isinstance(device, CloudFolder)
    with device:
        assert [p.name for p in device.files] == ["scan1.npy", "scan2.pcd", "scan3.pcd", "scan10.npy"]
        first = device.read()
        np.testing.assert_array_equal(first.points, clouds[0])
        assert first.intensity is None and first.image is None
        assert first.meta == {"source": "scan1.npy", "frame_index": 0, "dropped_non_finite": 0}
        second = device.read()
        np.testing.assert_allclose(second.points, clouds[1], atol=1e-5)
        assert second.meta["frame_index"] == 1
        with pytest.raises(InputError) as info:
            device.read()
        assert info.value.input == str(tmp_path / "rec" / "scan3.pcd")
        last = device.read()
        assert last.meta == {"source": "scan10.npy", "frame_index": 3, "dropped_non_finite": 1}
        np.testing.assert_array_equal(last.points, clouds[2])
        with pytest.raises(DeviceDisconnected, match="end of recording after 4 clouds"):
            device.read()
    assert "cloud_files" in device.describe()


def test_cloud_folder_single_file_loop_and_pattern(tmp_path: Path) -> None:
    clouds = write_recording(tmp_path / "rec")
    with create_device({"driver": "cloud_files", "path": str(tmp_path / "rec" / "scan1.npy"), "loop": True}) as dev:
        for _ in range(3):
            np.testing.assert_array_equal(dev.read().points, clouds[0])
    with create_device({"driver": "cloud_files", "path": str(tmp_path / "rec"), "pattern": "*.npy"}) as dev:
        assert [dev.read().meta["source"] for _ in range(2)] == ["scan1.npy", "scan10.npy"]
        with pytest.raises(DeviceDisconnected):
            dev.read()


def test_cloud_folder_real_pair() -> None:
    with create_device({"driver": "cloud_files", "path": str(require(P64).parent), "pattern": "*.pcd"}) as dev:
        sources = [dev.read() for _ in range(2)]
    assert [s.meta["source"] for s in sources] == ["p64.pcd", "qt.pcd"]
    assert [len(s.points) for s in sources] == [77_547, 12_414]
    assert all(s.intensity is not None for s in sources)


def test_cloud_folder_open_errors(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    (tmp_path / "scan.xyz").write_text("1 2 3\n")
    for path in (tmp_path / "missing", tmp_path / "empty", tmp_path / "scan.xyz"):
        device = create_device({"driver": "cloud_files", "path": str(path)})
        with pytest.raises(DeviceError) as info:
            device.open()
        assert info.value.device == str(path)
    with pytest.raises(DeviceError, match="not open"):
        CloudFolder(str(tmp_path)).read()
