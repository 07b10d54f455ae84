"""Depth sources: the shared depth-sample conversion, the Kinect v2 and RealSense frame conversions (no hardware),
the depth_files folder reader and depth topics of ROS 2 bags, each against a ray-cast scene with known geometry.

The scene, in the camera's optical frame (X right, Y down, Z out, m): a background plane ``z - 0.5 y = 3`` (tilted
about X) and, in front of it on the right of the view, a bright fronto-parallel box face ``z = 2`` for ``0.1 <= x
<= 0.5``, ``|y| <= 0.2``. Depth images are rendered through the lens *with* its distortion (each pixel's ray from
OpenCV's iterative undistortion), so the conversions must undo the lens to put every point back on a surface.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from backend.core.camera import CameraIntrinsics
from backend.core.depth import DepthIntrinsics
from backend.core.errors import InputError
from backend.devices.base import DeviceDisconnected, DeviceError, Sample, create_device, driver_names
from backend.devices.depth_files import depth_sample, pinhole_of, undistort_depth
from backend.devices.kinect2 import MISSING_MESSAGE as KINECT_MISSING
from backend.devices.kinect2 import Kinect2Camera, kinect_frame_to_sample, kinect_ir_camera
from backend.devices.realsense import MISSING_MESSAGE as REALSENSE_MISSING
from backend.devices.realsense import RealSenseCamera, realsense_camera, realsense_frame_to_sample
from backend.devices.rosbag_source import RosbagError, RosbagSource
from backend.exports.ros_camera_info import write_camera_info

BACKGROUND = np.array([0.0, -0.5, 1.0]) / np.linalg.norm([0.0, -0.5, 1.0])
"""Unit normal of the background plane; its offset is :data:`BACKGROUND_D` (m)."""
BACKGROUND_D = 3.0 / np.linalg.norm([0.0, -0.5, 1.0])
BOX_Z, BOX_X, BOX_Y = 2.0, (0.1, 0.5), 0.2
"""The box face: depth (m), its x range and half-height (m)."""
AMPLITUDE_BACKGROUND, AMPLITUDE_BOX = 100.0, 1000.0

KINECT_PARAMS = SimpleNamespace(fx=365.456, fy=365.456, cx=254.878, cy=205.395, k1=0.0905474, k2=-0.26819,
                                k3=0.0950862, p1=0.002, p2=-0.004)
"""libfreenect2 IrCameraParams of a real Kinect v2 (radial terms), with tangential terms made up so their signs
matter."""
SMALL = CameraIntrinsics("pinhole-radtan", 160, 120, [[120.0, 0, 79.2], [0, 121.0, 59.7], [0, 0, 1]],
                         [0.08, -0.2, 0.001, -0.002, 0.05])
"""A small lens with distortion, for the files and the bags (fast to write and read)."""


def ray_cast(rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth Z (m) and amplitude of the scene along rays (N, 3) with Z = 1 (camera frame)."""
    z_background = BACKGROUND_D / (rays @ BACKGROUND)
    x, y = rays[:, 0] * BOX_Z, rays[:, 1] * BOX_Z
    on_box = (x >= BOX_X[0]) & (x <= BOX_X[1]) & (np.abs(y) <= BOX_Y)
    return np.where(on_box, BOX_Z, z_background), np.where(on_box, AMPLITUDE_BOX, AMPLITUDE_BACKGROUND)


def render(camera: CameraIntrinsics, mirror: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Depth (m) and amplitude images (H, W float32) the scene gives through ``camera``'s distorted lens; with
    ``mirror`` the image is what libfreenect2 delivers: ``camera`` is the mirrored image's own model and each
    pixel sees the mirror image of its ray (x negated)."""
    v, u = np.mgrid[0:camera.height, 0:camera.width]
    pixels = np.column_stack([u.ravel(), v.ravel()]).astype(float)
    if np.any(camera.dist):
        xy = camera.undistort_points(pixels)
    else:
        xy = (pixels - camera.K[:2, 2]) / np.diag(camera.K)[:2]
    if mirror:
        xy[:, 0] *= -1
    depth, amplitude = ray_cast(np.column_stack([xy, np.ones(len(xy))]))
    shape = (camera.height, camera.width)
    return depth.reshape(shape).astype(np.float32), amplitude.reshape(shape).astype(np.float32)


def surface_error(points: np.ndarray) -> np.ndarray:
    """Distance (m) of each point (N, 3) to the nearer scene surface."""
    to_background = np.abs(points @ BACKGROUND - BACKGROUND_D)
    x, y = points[:, 0], points[:, 1]
    on_box_face = (x >= BOX_X[0] - 0.01) & (x <= BOX_X[1] + 0.01) & (np.abs(y) <= BOX_Y + 0.01)
    to_box = np.where(on_box_face, np.abs(points[:, 2] - BOX_Z), np.inf)
    return np.minimum(to_background, to_box)


def check_scene(sample: Sample, tolerance_m: float = 0.0015, min_fraction: float = 0.95) -> None:
    """Nearly every pixel gave a point, 95 % of them lie on a scene surface within ``tolerance_m`` (interpolated
    depth) and all within the edge bound: where resampling takes the nearest pixel (a depth edge), a point may
    sit up to half a pixel diagonal (0.71 px, i.e. 0.71 z / fx m) sideways along the background, whose depth
    changes by 0.5 m per m of y. The bright points are the box face, on the right (x > 0), centred at x = 0.3 m
    and y = 0 within half a pixel."""
    height, width = sample.depth.shape
    assert sample.depth.dtype == np.float32 and sample.points.shape[1] == 3
    assert len(sample.points) >= min_fraction * width * height
    pinhole = DepthIntrinsics.from_dict(sample.meta["intrinsics"])
    error = surface_error(sample.points)
    assert np.mean(error < tolerance_m) > 0.95
    assert error.max() < tolerance_m + 0.71 * sample.points[:, 2].max() / pinhole.fx * 0.5
    index = sample.meta["pixel_index"]
    np.testing.assert_allclose(pinhole.unproject(sample.depth)[0], sample.points)  # depth + pinhole = the points
    if sample.intensity is not None:
        assert sample.intensity.dtype == np.float32 and sample.intensity.shape == index.shape
        bright = sample.points[sample.intensity > (AMPLITUDE_BACKGROUND + AMPLITUDE_BOX) / 2]
        assert len(bright) > 20 and (bright[:, 0] > 0).all()
        # half a pixel: where the box's edges fall on the pixel grid (a principal point a pixel off shows)
        assert np.mean(bright[:, 0]) == pytest.approx(np.mean(BOX_X), abs=0.5 * BOX_Z / pinhole.fx)
        assert np.mean(bright[:, 1]) == pytest.approx(0.0, abs=0.5 * BOX_Z / pinhole.fy)
        assert np.abs(bright[:, 2] - BOX_Z).max() < tolerance_m  # a fronto-parallel face: no sideways error


# --- the shared conversion ------------------------------------------------------------------


KINECT_LIKE = CameraIntrinsics("pinhole-radtan", 512, 424, [[KINECT_PARAMS.fx, 0, KINECT_PARAMS.cx],
                                                              [0, KINECT_PARAMS.fy, KINECT_PARAMS.cy], [0, 0, 1]],
                               [KINECT_PARAMS.k1, KINECT_PARAMS.k2, KINECT_PARAMS.p1, KINECT_PARAMS.p2,
                                KINECT_PARAMS.k3])
"""The Kinect v2's IR lens as OpenCV states it for the image libfreenect2 delivers."""


@pytest.fixture(scope="module")
def kinect_views() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Depth (m) and amplitude through :data:`KINECT_LIKE`: ``plain`` as an optical camera sees the scene,
    ``mirrored`` as libfreenect2 delivers it (rendered once: 217k rays each)."""
    return {"plain": render(KINECT_LIKE), "mirrored": render(KINECT_LIKE, mirror=True)}


def test_undistorted_depth_lies_on_the_scene_and_the_pinhole_alone_does_not(kinect_views: dict) -> None:
    depth, amplitude = kinect_views["plain"]
    pinhole = pinhole_of(KINECT_LIKE, 0.5, 9.0)
    undistorted, undistorted_amplitude = undistort_depth(depth, amplitude, KINECT_LIKE)
    sample = depth_sample(undistorted, pinhole, 1.5, "test", undistorted_amplitude, {"source": "x"})
    check_scene(sample)
    assert sample.timestamp_s == 1.5 and sample.meta["source"] == "x"
    # no point in the air between the box face and the plane behind it (no interpolation across the edge)
    assert not ((sample.points[:, 2] > BOX_Z + 0.01) & (surface_error(sample.points) > 0.004)).any()
    naive = depth_sample(depth, pinhole, 0.0, "test")  # the distorted image read as a pinhole
    assert np.percentile(surface_error(naive.points), 99) > 0.02


def test_depth_sample_cleans_and_refuses() -> None:
    pinhole = DepthIntrinsics(4, 3, 3.0, 3.0, 1.5, 1.0, 0.5, 5.0)
    depth = np.full((3, 4), 2.0, np.float32)
    depth[0, 0], depth[0, 1], depth[0, 2], depth[1, 1] = np.nan, -1.0, np.inf, 7.0
    sample = depth_sample(depth, pinhole, 0.0, "cam", np.arange(12, dtype=np.float32).reshape(3, 4))
    assert sample.depth[0, :3].tolist() == [0, 0, 0] and sample.depth[1, 1] == 7.0  # beyond range: kept, no point
    assert sample.meta["pixel_index"].tolist() == [3, 4, 6, 7, 8, 9, 10, 11]
    np.testing.assert_array_equal(sample.intensity, [3, 4, 6, 7, 8, 9, 10, 11])
    np.testing.assert_array_equal(sample.meta["amplitude"].ravel(), np.arange(12))  # pixels without depth too
    assert "pixel_index" not in sample.storable_meta() and sample.storable_meta()["intrinsics"]["width"] == 4
    with pytest.raises(InputError, match="cam: no pixel .* within 0.5 to 5 m"):
        depth_sample(np.zeros((3, 4)), pinhole, 0.0, "cam")
    with pytest.raises(InputError, match="cam: the depth image is 3x4 px; its intrinsics say 4x3"):
        depth_sample(np.ones((4, 3)), pinhole, 0.0, "cam")
    with pytest.raises(InputError, match="amplitude"):
        depth_sample(depth, pinhole, 0.0, "cam", np.ones((2, 2)))


# --- Kinect v2 ------------------------------------------------------------------------------


def test_kinect_frame_is_flipped_undistorted_and_on_the_scene(kinect_views: dict) -> None:
    depth_m, ir = kinect_views["mirrored"]  # what libfreenect2 delivers (in mm)
    camera = kinect_ir_camera(KINECT_PARAMS)
    assert camera.K[0, 2] == pytest.approx(511 - KINECT_PARAMS.cx) and camera.dist[3] == -KINECT_PARAMS.p2
    sample = kinect_frame_to_sample(depth_m * 1000, ir, camera, 2.0, meta={"serial": "007"})
    check_scene(sample)
    assert sample.meta["serial"] == "007" and sample.meta["intrinsics"]["cx"] == pytest.approx(511 - 254.878)
    unflipped = kinect_frame_to_sample(np.fliplr(depth_m * 1000), np.fliplr(ir), camera, 2.0)
    assert np.mean(unflipped.points[unflipped.intensity > 500][:, 0]) < 0  # a mirrored cloud puts the box left


def test_kinect_missing_library_and_settings(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "pylibfreenect2", None)  # import fails as when it is not installed
    device = create_device({"driver": "kinect2", "serial": "012345"})
    with pytest.raises(DeviceError) as info:
        device.open()
    assert info.value.message == KINECT_MISSING and "kinect2 012345" in str(info.value)
    with pytest.raises(DeviceError, match="not open"):
        device.read()
    device.close()
    for settings, words in [({"pipeline": "vulkan"}, "pipeline must be one of auto, cuda"),
                            ({"timeout_s": 0}, "timeout_s"), ({"timeout_s": True}, "timeout_s"),
                            ({"min_range_m": 5, "max_range_m": 1}, "min < max"),
                            ({"max_range_m": "far"}, "max_range_m"), ({"colour": True}, "bad settings")]:
        with pytest.raises(DeviceError, match=words):
            create_device({"driver": "kinect2", **settings})
    assert {"kinect2", "realsense", "depth_files"} <= set(driver_names())


class FakeFrame:
    def __init__(self, image: np.ndarray, timestamp: int):
        self.image, self.timestamp, self.sequence = image, timestamp, timestamp // 10

    def asarray(self, dtype: type) -> np.ndarray:
        return self.image.astype(dtype)


def fake_pylibfreenect2(frames: list[dict], serials: tuple[bytes, ...] = (b"007",)) -> SimpleNamespace:
    """pylibfreenect2's calls the driver makes, answering with ``frames`` then timeouts; ``released`` counts
    frame maps handed back, ``calls`` what was called on the device."""
    calls: list[str] = []

    class Device:
        def setIrAndDepthFrameListener(self, listener: object) -> None:
            calls.append("listener")

        def startStreams(self, rgb: bool, depth: bool) -> None:
            calls.append(f"start rgb={rgb} depth={depth}")

        def getIrCameraParams(self) -> SimpleNamespace:
            return KINECT_PARAMS

        def stop(self) -> None:
            calls.append("stop")

        def close(self) -> None:
            calls.append("close")

    class Freenect2:
        def enumerateDevices(self) -> int:
            return len(serials)

        def getDeviceSerialNumber(self, index: int) -> bytes:
            return serials[index]

        def openDevice(self, serial: bytes, pipeline: object) -> Device:
            calls.append(f"open {serial!r} {type(pipeline).__name__}")
            return Device()

    class SyncMultiFrameListener:
        def __init__(self, types: int):
            calls.append(f"types {types}")

        def waitForNewFrame(self, milliseconds: int) -> dict | None:
            return frames.pop(0) if frames else None

        def release(self, frame_map: dict) -> None:
            library.released += 1

    class CpuPacketPipeline:
        pass

    library = SimpleNamespace(Freenect2=Freenect2, SyncMultiFrameListener=SyncMultiFrameListener,
                              FrameType=SimpleNamespace(Color=1, Ir=2, Depth=4), CpuPacketPipeline=CpuPacketPipeline,
                              released=0, calls=calls)
    return library


def test_kinect_driver_through_the_library_calls(monkeypatch: pytest.MonkeyPatch, kinect_views: dict) -> None:
    depth_m, ir = kinect_views["mirrored"]
    library = fake_pylibfreenect2([{"depth": FakeFrame(depth_m * 1000, 1230), "ir": FakeFrame(ir, 1230)}])
    monkeypatch.setitem(sys.modules, "pylibfreenect2", library)
    with pytest.raises(DeviceError, match="no Kinect v2 with serial 999; found 007"):
        Kinect2Camera(serial="999").open()
    with pytest.raises(DeviceError, match="without the cuda pipeline"):
        Kinect2Camera(pipeline="cuda").open()
    with create_device({"driver": "kinect2", "timeout_s": 0.1}) as device:
        sample = device.read()
        check_scene(sample)
        assert sample.meta["serial"] == "007" and sample.meta["device_timestamp"] == 1230
        assert sample.meta["undistorted_from"]["dist"][3] == -KINECT_PARAMS.p2 and library.released == 1
        with pytest.raises(DeviceDisconnected, match="no frame within 0.1 s"):
            device.read()
        assert device.describe() == "kinect2 007 (auto pipeline)"
    assert library.calls[-5:] == ["types 6", "listener", "start rgb=False depth=True", "stop", "close"]
    assert "open b'007' CpuPacketPipeline" in library.calls
    library.Freenect2.enumerateDevices = lambda self: 0
    with pytest.raises(DeviceError, match="no Kinect v2 found"):
        Kinect2Camera().open()


# --- RealSense ------------------------------------------------------------------------------


def realsense_intrinsics(coeffs: list[float] | None = None) -> SimpleNamespace:
    return SimpleNamespace(width=424, height=240, fx=210.7, fy=210.7, ppx=212.4, ppy=119.6,
                           model=SimpleNamespace(name="brown_conrady"), coeffs=coeffs or [0.0] * 5)


@pytest.fixture(scope="module")
def realsense_view() -> tuple[np.ndarray, np.ndarray]:
    """Depth (m) and amplitude of the scene through a RealSense's 424x240 pinhole."""
    return render(realsense_camera(realsense_intrinsics()))


def test_realsense_frame_to_sample_and_refused_lens(realsense_view: tuple[np.ndarray, np.ndarray]) -> None:
    camera = realsense_camera(realsense_intrinsics())
    depth_m, ir = realsense_view
    z16 = np.rint(depth_m / 0.001).astype(np.uint16)  # D400 depth units: 1 mm
    sample = realsense_frame_to_sample(z16, 0.001, ir.astype(np.uint16), camera, 3.0, meta={"frame_number": 5})
    check_scene(sample, tolerance_m=0.0006, min_fraction=0.999)  # half a depth unit, no lens
    assert sample.meta["depth_scale_m"] == 0.001 and sample.meta["intrinsics"]["cx"] == 212.4
    assert realsense_frame_to_sample(z16, 0.001, None, camera, 3.0).intensity is None
    with pytest.raises(DeviceError, match=r"brown_conrady distortion \[0.1, 0.0"):
        realsense_camera(realsense_intrinsics([0.1, 0, 0, 0, 0]), "realsense 123")


def test_realsense_missing_library_and_settings(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)
    with pytest.raises(DeviceError) as info:
        create_device({"driver": "realsense"}).open()
    assert info.value.message == REALSENSE_MISSING
    for settings, words in [({"width": 0}, "width must be an integer"), ({"fps": "30"}, "fps"),
                            ({"timeout_s": -1}, "timeout_s"), ({"min_range_m": -0.1}, "min_range_m")]:
        with pytest.raises(DeviceError, match=words):
            RealSenseCamera(**settings)
    assert RealSenseCamera(serial="123").describe() == "realsense 123 848x480 at 30 Hz"


def fake_pyrealsense2(frame_sets: list[tuple[np.ndarray, np.ndarray]], connected: bool = True) -> SimpleNamespace:
    """pyrealsense2's calls the driver makes: ``frame_sets`` of (z16, infrared) then timeouts; ``calls`` records
    the configuration and the stop."""
    calls: list[str] = []

    class Frame:
        def __init__(self, data: np.ndarray, number: int):
            self.data, self.number = data, number

        def get_data(self) -> np.ndarray:
            return self.data

        def get_timestamp(self) -> float:
            return 1000.0 + self.number

        def get_frame_number(self) -> int:
            return self.number

    class FrameSet:
        def __init__(self, z16: np.ndarray, infrared: np.ndarray, number: int):
            self.depth, self.infrared = Frame(z16, number), Frame(infrared, number)

        def get_depth_frame(self) -> Frame:
            return self.depth

        def get_infrared_frame(self, index: int) -> Frame:
            calls.append(f"infrared {index}")
            return self.infrared

    class Profile:
        def get_device(self) -> SimpleNamespace:
            sensor = SimpleNamespace(get_depth_scale=lambda: 0.001)
            return SimpleNamespace(first_depth_sensor=lambda: sensor, get_info=lambda key: f"SN-{key}")

        def get_stream(self, stream: str) -> SimpleNamespace:
            video = SimpleNamespace(get_intrinsics=realsense_intrinsics)
            return SimpleNamespace(as_video_stream_profile=lambda: video)

    class Pipeline:
        def start(self, config: object) -> Profile:
            if not connected:
                raise RuntimeError("No device connected")
            return Profile()

        def try_wait_for_frames(self, timeout_ms: int) -> tuple[bool, FrameSet | None]:
            if not frame_sets:
                return False, None
            return True, FrameSet(*frame_sets.pop(0), number=7)

        def stop(self) -> None:
            calls.append("stop")

    class Config:
        def enable_device(self, serial: str) -> None:
            calls.append(f"device {serial}")

        def enable_stream(self, *args: object) -> None:
            calls.append("stream " + " ".join(str(a) for a in args))

    return SimpleNamespace(pipeline=Pipeline, config=Config, calls=calls,
                           stream=SimpleNamespace(depth="depth", infrared="infrared"),
                           format=SimpleNamespace(z16="z16", y8="y8"), camera_info=SimpleNamespace(serial_number="sn"))


def test_realsense_driver_through_the_library_calls(monkeypatch: pytest.MonkeyPatch,
                                                   realsense_view: tuple[np.ndarray, np.ndarray]) -> None:
    depth_m, ir = realsense_view
    library = fake_pyrealsense2([(np.rint(depth_m * 1000).astype(np.uint16), ir.astype(np.uint16))])
    monkeypatch.setitem(sys.modules, "pyrealsense2", library)
    with create_device({"driver": "realsense", "serial": "42", "width": 424, "height": 240,
                        "timeout_s": 0.1}) as device:
        sample = device.read()
        with pytest.raises(DeviceDisconnected, match="no frame within 0.1 s"):
            device.read()
        assert device.describe() == "realsense SN-sn 424x240 at 30 Hz"
    check_scene(sample, tolerance_m=0.0006, min_fraction=0.999)
    assert sample.meta["serial"] == "SN-sn" and sample.meta["frame_number"] == 7
    assert sample.meta["device_timestamp_ms"] == 1007.0 and sample.meta["depth_scale_m"] == 0.001
    assert library.calls == ["device 42", "stream depth 424 240 z16 30", "stream infrared 1 424 240 y8 30",
                             "infrared 1", "stop"]
    monkeypatch.setitem(sys.modules, "pyrealsense2", fake_pyrealsense2([], connected=False))
    with pytest.raises(DeviceError, match="cannot start 848x480 depth at 30 Hz: No device connected"):
        RealSenseCamera().open()


# --- depth_files ----------------------------------------------------------------------------


def write_png(path: Path, image: np.ndarray) -> Path:
    assert cv2.imwrite(str(path), image)
    return path


@pytest.fixture(scope="module")
def depth_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two 16-bit PNG depth images in mm (the first with an _ir image) and an intrinsics.json with the lens."""
    folder = tmp_path_factory.mktemp("depth")
    depth_m, ir = render(SMALL)
    write_png(folder / "frame1.png", np.rint(depth_m * 1000).astype(np.uint16))
    write_png(folder / "frame1_ir.png", ir.astype(np.uint16))
    write_png(folder / "frame2.png", np.rint(depth_m * 1000).astype(np.uint16))
    K = SMALL.K
    (folder / "intrinsics.json").write_text(json.dumps({
        "width": 160, "height": 120, "fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2],
        "max_range_m": 8.0, "dist": SMALL.dist.tolist()}))
    return folder


def test_depth_files_png_with_amplitude_and_json_intrinsics(depth_folder: Path) -> None:
    device = create_device({"driver": "depth_files", "path": str(depth_folder)})
    with device:
        assert [f.name for f in device.files] == ["frame1.png", "frame2.png"]
        first, second = device.read(), device.read()
        with pytest.raises(DeviceDisconnected, match="after 2 depth images"):
            device.read()
        assert device.describe().endswith("(2 depth images) 160x120")
    check_scene(first)
    assert first.meta["source"] == "frame1.png" and first.meta["amplitude_source"] == "frame1_ir.png"
    assert first.meta["intrinsics"]["max_range_m"] == 8.0 and first.meta["intrinsics"]["min_range_m"] == 0.5
    assert second.intensity is None and second.meta["frame_index"] == 1
    np.testing.assert_array_equal(second.points, first.points)


def test_depth_files_npy_with_camera_info_yaml(tmp_path: Path) -> None:
    depth_m, ir = render(SMALL)
    depth_m[5, 5] = np.nan
    np.save(tmp_path / "a.npy", depth_m)
    np.save(tmp_path / "a_amplitude.npy", ir)
    write_camera_info(tmp_path / "lens.yaml", SMALL, "depth")
    with create_device({"driver": "depth_files", "path": str(tmp_path), "intrinsics": "lens.yaml",
                        "min_range_m": 1.0}) as device:
        sample = device.read()
    check_scene(sample)
    assert sample.meta["intrinsics"]["min_range_m"] == 1.0 and sample.meta["intrinsics"]["max_range_m"] == 9.0


def test_depth_files_bad_files_are_named_and_skipped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    depth_mm = np.rint(render(SMALL)[0] * 1000).astype(np.uint16)
    write_png(tmp_path / "1.png", depth_mm.astype(np.uint8))
    (tmp_path / "2.png").write_bytes(write_png(tmp_path / "2.png", depth_mm).read_bytes()[:300])
    np.save(tmp_path / "3.npy", np.zeros((120, 160), np.int32))
    write_png(tmp_path / "4.png", depth_mm)
    write_png(tmp_path / "4_ir.png", np.zeros((10, 10), np.uint8))
    write_png(tmp_path / "5.png", depth_mm[:50])
    write_png(tmp_path / "6.png", depth_mm)
    write_camera_info(tmp_path / "camera_info.yaml", SMALL, "depth")
    expected = ["1.png: a 8-bit PNG with 1 channel(s); expected a single-channel 16-bit PNG",
                "2.png: the PNG cannot be decoded", "3.npy: an array of shape (120, 160) and dtype int32",
                "4_ir.png: 10x10 px, but its depth image 4.png is 160x120", "5.png: the depth image is 160x50 px"]
    with create_device({"driver": "depth_files", "path": str(tmp_path)}) as device:
        for words in expected:
            with pytest.raises(InputError, match=words.replace("(", r"\(").replace(")", r"\)")) as info:
                device.read()
            assert info.value.input.endswith(words.split(":")[0])
        assert device.read().meta["source"] == "6.png"  # reading goes on after each bad file
    monkeypatch.setenv("CALIB_MAX_IMAGE_PIXELS", "1000")
    with create_device({"driver": "depth_files", "path": str(tmp_path), "pattern": "6*"}) as device:
        with pytest.raises(InputError, match="160x120 px.*CALIB_MAX_IMAGE_PIXELS") as info:
            device.read()
    assert info.value.status_code == 413


def test_depth_files_intrinsics_problems_fail_the_open(tmp_path: Path) -> None:
    write_png(tmp_path / "1.png", np.ones((120, 160), np.uint16))
    with pytest.raises(DeviceError, match="no intrinsics file: expected one of intrinsics.json"):
        create_device({"driver": "depth_files", "path": str(tmp_path)}).open()
    for document, words in [("{", "not valid JSON"), ('{"width": 160}', "field 'height' is missing"),
                            ('{"width": 160.5, "height": 120, "fx": 1, "fy": 1, "cx": 0, "cy": 0}', "field 'width'"),
                            ('{"width": 160, "height": 120, "fx": 1, "fy": 1, "cx": 0, "cy": 0, "dist": [1]}',
                             "field 'dist' is \\[1\\]; expected five numbers")]:
        (tmp_path / "intrinsics.json").write_text(document)
        with pytest.raises(DeviceError, match=words) as info:
            create_device({"driver": "depth_files", "path": str(tmp_path)}).open()
        assert str(tmp_path / "intrinsics.json") in str(info.value)
    with pytest.raises(DeviceError, match="min < max"):
        create_device({"driver": "depth_files", "path": str(tmp_path), "max_range_m": 0.2})


# --- ROS 2 bags -----------------------------------------------------------------------------

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types


def header(sec: int) -> object:
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=0), frame_id="depth")


def image_msg(pixels: np.ndarray, encoding: str, big_endian: bool = False, pad: int = 0) -> object:
    height, width = pixels.shape
    dtype = pixels.dtype.newbyteorder(">" if big_endian else "<")
    rows = np.ascontiguousarray(pixels.astype(dtype)).view(np.uint8).reshape(height, -1)
    rows = np.concatenate([rows, np.zeros((height, pad), np.uint8)], axis=1)
    return T["sensor_msgs/msg/Image"](header=header(100), height=height, width=width, encoding=encoding,
                                      is_bigendian=int(big_endian), step=rows.shape[1], data=rows.ravel())


def camera_info_msg(camera: CameraIntrinsics) -> object:
    P = np.zeros((3, 4))
    P[:, :3] = camera.K
    return T["sensor_msgs/msg/CameraInfo"](
        header=header(100), height=camera.height, width=camera.width, distortion_model="plumb_bob",
        d=camera.dist.copy(), k=camera.K.ravel(), r=np.eye(3).ravel(), p=P.ravel(), binning_x=0, binning_y=0,
        roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))


@pytest.fixture(scope="module")
def depth_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """/cam/depth: 16UC1 mm (big-endian, padded rows) with its camera_info beside it; /other/image: 32FC1 m with
    NaN holes, its camera on /cam/depth/camera_info; /bare/image: 16UC1 and 32FC1 without any camera_info."""
    depth_m = render(SMALL)[0]
    holes = depth_m.copy()
    holes[::7, ::5] = np.nan
    mm = np.rint(depth_m * 1000).astype(np.uint16)
    topics = {"/cam/depth/image_raw": ("sensor_msgs/msg/Image", [image_msg(mm, "16UC1", True, 6)]),
              "/cam/depth/camera_info": ("sensor_msgs/msg/CameraInfo", [camera_info_msg(SMALL)]),
              "/other/image": ("sensor_msgs/msg/Image", [image_msg(holes, "32FC1")]),
              "/bare/image": ("sensor_msgs/msg/Image", [image_msg(mm, "16UC1"), image_msg(holes, "32FC1")])}
    path = tmp_path_factory.mktemp("bags") / "depth"
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for topic, (msgtype, msgs) in topics.items():
            connection = writer.add_connection(topic, msgtype, typestore=TS)
            for i, msg in enumerate(msgs):
                writer.write(connection, 10**18 + i * 10**8, TS.serialize_cdr(msg, msgtype))
    return path


def test_rosbag_depth_topics_with_their_camera_info(depth_bag: Path) -> None:
    with create_device({"driver": "rosbag", "path": str(depth_bag), "topic": "/cam/depth/image_raw"}) as device:
        sample = device.read()
    check_scene(sample)
    assert sample.image is None and sample.timestamp_s == 100.0 and sample.meta["topic"] == "/cam/depth/image_raw"
    assert sample.meta["undistorted_from"]["dist"] == pytest.approx(SMALL.dist.tolist())
    with create_device({"driver": "rosbag", "path": str(depth_bag), "topic": "/other/image",
                        "camera_info_topic": "/cam/depth/camera_info", "max_range_m": 3.0}) as device:
        holes = device.read()
    n_holes = holes.depth[::7, ::5].size  # NaN in the bag: no return, moved by the undistortion
    assert 0.8 * n_holes <= (holes.depth == 0).sum() <= 1.5 * n_holes
    error = surface_error(holes.points)  # beside a hole resampling takes the nearest pixel (see check_scene)
    assert holes.points[:, 2].max() <= 3.0 and np.median(error) < 0.0015
    assert error.max() < 0.0015 + 0.71 * 3.0 / SMALL.K[0, 0] * 0.5


def test_rosbag_depth_without_camera_info(depth_bag: Path) -> None:
    with RosbagSource(str(depth_bag), "/bare/image") as device:
        gray = device.read()  # 16UC1 without a camera: a gray image, as before
        assert gray.image.dtype == np.uint8 and gray.depth is None
        with pytest.raises(InputError, match="32FC1 depth image needs its camera: .* '/bare/camera_info'"):
            device.read()
    with pytest.raises(RosbagError, match="no CameraInfo topic '/nope/camera_info'.*available topics"):
        RosbagSource(str(depth_bag), "/bare/image", camera_info_topic="/nope/camera_info").open()
