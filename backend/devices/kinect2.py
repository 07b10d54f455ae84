"""Kinect v2 time-of-flight depth through libfreenect2 (driver ``"kinect2"``, optional extra ``kinect2``).

``pylibfreenect2`` (``pip install 'calib-studio[kinect2]'``) builds against libfreenect2, which must be installed
first; it is imported only in :meth:`Kinect2Camera.open`, so everything else works without it.

What libfreenect2 delivers and what the driver makes of it (:func:`kinect_frame_to_sample`, a pure function):

- depth (424 x 512 float32, mm, 0 = no return) and IR amplitude (float32, 0..65535) images, **mirrored** left to
  right (libfreenect2 issue #172: every image is, as in the Kinect SDK). They are flipped back, so the image is what
  an optical camera sees (X right, Y down, Z out of the lens; the node frame of ``backend.core.depth``).
- the device's factory IR intrinsics (``getIrCameraParams``: fx, fy, cx, cy in px and the radial-tangential
  k1, k2, k3, p1, p2 that libfreenect2's ``Registration`` undistorts with). :func:`kinect_ir_camera` states them
  for the flipped image: ``cx`` becomes ``width - 1 - cx`` and ``p2`` changes sign (mirroring x negates the
  x-tangential term). The images are then resampled onto the undistorted pinhole
  (:func:`~backend.devices.depth_files.undistort_depth`: the Kinect v2's lens moves corner pixels by about 20 px)
  and that pinhole goes into ``Sample.meta["intrinsics"]``.

libfreenect2 names pixel centres two ways: its undistortion (``Registration::distort``) puts the top-left pixel's
centre at 0 like OpenCV, its ``getPointXYZ`` at 0.5. The driver follows the undistortion (and the conventions),
so its points can differ from ``getPointXYZ`` by half a pixel (about 7 mm sideways at 5 m).

pylibfreenect2 0.1.4 does not expose ``Freenect2Device::setConfiguration``, so libfreenect2's default depth
window applies: returns beyond :data:`LIBFREENECT2_MAX_DEPTH_M` (4.5 m) come back as 0. A cell with ceiling
nodes at 5 m needs a libfreenect2 built with a larger ``MaxDepth`` default (or a binding that sets it); the driver
logs this when its range asks for more.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from backend.core.camera import CameraIntrinsics
from backend.core.depth import KINECT_V2
from backend.devices.base import CaptureDevice, DeviceDisconnected, DeviceError, Sample, register_driver
from backend.devices.depth_files import MM_PER_M, check_ranges, depth_sample, pinhole_of, undistort_depth

log = logging.getLogger(__name__)

MISSING_MESSAGE = "pylibfreenect2 is not installed: pip install 'calib-studio[kinect2]' (needs libfreenect2)"
PIPELINES = ("auto", "cuda", "opencl", "opengl", "cpu")
"""Depth packet pipelines by name; ``auto`` takes the first of the others that this libfreenect2 was built with."""
_PIPELINE_CLASSES = {"cuda": "CudaPacketPipeline", "opencl": "OpenCLPacketPipeline",
                     "opengl": "OpenGLPacketPipeline", "cpu": "CpuPacketPipeline"}
LIBFREENECT2_MAX_DEPTH_M = 4.5
"""libfreenect2's default ``Config::MaxDepth`` (m): depth beyond it is returned as 0."""


def kinect_ir_camera(params: Any, width: int = KINECT_V2.width, height: int = KINECT_V2.height) -> CameraIntrinsics:
    """The Kinect's IR (depth) camera for the flipped (un-mirrored) image, from libfreenect2's ``IrCameraParams``
    (any object with ``fx, fy, cx, cy`` in px and ``k1, k2, k3, p1, p2``) of the mirrored image."""
    fx, fy, cx, cy = (float(getattr(params, name)) for name in ("fx", "fy", "cx", "cy"))
    k1, k2, k3, p1, p2 = (float(getattr(params, name)) for name in ("k1", "k2", "k3", "p1", "p2"))
    K = np.array([[fx, 0.0, width - 1 - cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return CameraIntrinsics("pinhole-radtan", width, height, K, [k1, k2, p1, -p2, k3])


def kinect_frame_to_sample(depth_mm: np.ndarray, ir: np.ndarray, camera: CameraIntrinsics, timestamp_s: float,
                           min_range_m: float = 0.5, max_range_m: float = 9.0,
                           meta: dict[str, Any] | None = None, source: str = "kinect2") -> Sample:
    """The depth :class:`Sample` of one libfreenect2 frame: ``depth_mm`` and ``ir`` as libfreenect2 gives them
    (H, W float32, mirrored; depth in mm, 0 = no return), ``camera`` from :func:`kinect_ir_camera`.

    The images are flipped, converted to metres, undistorted and unprojected (node frame, m) with the IR
    amplitude as intensity; see the module docs.
    """
    depth = np.fliplr(np.asarray(depth_mm, dtype=np.float32)) / np.float32(MM_PER_M)
    amplitude = np.fliplr(np.asarray(ir, dtype=np.float32))
    depth, amplitude = undistort_depth(depth, amplitude, camera)
    return depth_sample(depth, pinhole_of(camera, min_range_m, max_range_m), timestamp_s, source, amplitude,
                        {"mirrored_by_device": True, **(meta or {})})


def _text(value: bytes | str) -> str:
    """A serial number as text (pylibfreenect2 gives bytes, the std::string it wraps)."""
    return value.decode() if isinstance(value, bytes) else str(value)


@register_driver
class Kinect2Camera(CaptureDevice):
    """A Kinect v2 through libfreenect2: depth and IR at 30 Hz, as depth samples (see the module docs).

    ``serial`` picks one of several Kinects (default: the first found). ``pipeline`` is one of
    :data:`PIPELINES` (a Jetson: ``cuda``). ``timeout_s`` is how long :meth:`read` waits for a frame before it
    reports the device gone. ``min_range_m`` / ``max_range_m`` (m) bound the depth unprojected into points.
    Samples carry the read time as ``timestamp_s`` and meta ``serial``, ``device_timestamp`` (libfreenect2's,
    0.1 ms ticks), ``sequence`` and ``undistorted_from`` (the lens as the device states it).
    """

    driver = "kinect2"

    def __init__(self, serial: str | None = None, pipeline: str = "auto", timeout_s: float = 2.0,
                 min_range_m: float = 0.5, max_range_m: float = 9.0):
        self.serial = None if serial in (None, "") else str(serial)
        self.name = f"kinect2 {self.serial or '(first found)'}"
        if pipeline not in PIPELINES:
            raise DeviceError(f"pipeline must be one of {', '.join(PIPELINES)}, got {pipeline!r}", self.name)
        if isinstance(timeout_s, bool) or not isinstance(timeout_s, int | float) or not 0 < timeout_s < 60:
            raise DeviceError(f"timeout_s must be seconds between 0 and 60, got {timeout_s!r}", self.name)
        self.pipeline = pipeline
        self.timeout_s = float(timeout_s)
        self.min_range_m, self.max_range_m = check_ranges(min_range_m, max_range_m, self.name)
        self.camera: CameraIntrinsics | None = None
        """The IR camera of the flipped image, distortion included (known once open)."""
        self._freenect: Any = None
        self._device: Any = None
        self._listener: Any = None

    def _packet_pipeline(self, library: Any) -> Any:
        names = [self.pipeline] if self.pipeline != "auto" else list(_PIPELINE_CLASSES)
        for name in names:
            cls = getattr(library, _PIPELINE_CLASSES[name], None)
            if cls is not None:
                return cls()
        raise DeviceError(f"this libfreenect2 was built without the {self.pipeline} pipeline; try pipeline 'auto'",
                          self.name)

    def open(self) -> None:
        """Find and start the Kinect (depth and IR only); :class:`DeviceError` saying why it cannot."""
        self.close()
        try:
            import pylibfreenect2 as library
        except ImportError:
            raise DeviceError(MISSING_MESSAGE, self.name) from None
        freenect = library.Freenect2()
        count = freenect.enumerateDevices()
        if count == 0:
            raise DeviceError("no Kinect v2 found (libfreenect2 sees none: check the USB 3 port and the power "
                              "supply)", self.name)
        serials = {_text(raw): raw for raw in (freenect.getDeviceSerialNumber(i) for i in range(count))}
        if self.serial is not None and self.serial not in serials:
            raise DeviceError(f"no Kinect v2 with serial {self.serial}; found {', '.join(serials)}", self.name)
        serial = self.serial or next(iter(serials))
        device = freenect.openDevice(serials[serial], pipeline=self._packet_pipeline(library))
        listener = library.SyncMultiFrameListener(library.FrameType.Ir | library.FrameType.Depth)
        device.setIrAndDepthFrameListener(listener)
        device.startStreams(rgb=False, depth=True)
        self.camera = kinect_ir_camera(device.getIrCameraParams())
        self._freenect, self._device, self._listener = freenect, device, listener
        self.serial = serial
        self.name = f"kinect2 {serial}"
        if self.max_range_m > LIBFREENECT2_MAX_DEPTH_M:
            log.warning("%s: libfreenect2's default depth window ends at %.1f m (pylibfreenect2 cannot change it); "
                        "returns beyond it read as no return", self.name, LIBFREENECT2_MAX_DEPTH_M)

    def read(self) -> Sample:
        """The next depth + IR frame; :class:`DeviceDisconnected` when none comes within ``timeout_s``."""
        if self._listener is None or self.camera is None:
            raise DeviceError("not open; call open() first", self.name)
        frames = self._listener.waitForNewFrame(milliseconds=int(self.timeout_s * 1000))
        if frames is None:
            raise DeviceDisconnected(f"no frame within {self.timeout_s:g} s (unplugged?)", self.name)
        try:
            depth_frame, ir_frame = frames["depth"], frames["ir"]
            depth_mm = np.array(depth_frame.asarray(np.float32))  # copies: the buffers go back to libfreenect2
            ir = np.array(ir_frame.asarray(np.float32))
            meta = {"serial": self.serial, "device_timestamp": int(depth_frame.timestamp),
                    "sequence": int(depth_frame.sequence), "undistorted_from": self.camera.to_dict()}
        finally:
            self._listener.release(frames)
        return kinect_frame_to_sample(depth_mm, ir, self.camera, time.time(), self.min_range_m, self.max_range_m,
                                      meta, self.name)

    def close(self) -> None:
        """Stop and close the Kinect; safe to call twice."""
        device, self._device, self._listener = self._device, None, None
        if device is not None:
            try:
                device.stop()
                device.close()
            except Exception as exc:  # noqa: BLE001 - an unplugged device fails to stop; it is gone either way
                log.warning("%s: closing failed: %s", self.name, exc)
        self._freenect = None

    def describe(self) -> str:
        return f"{self.name} ({self.pipeline} pipeline)"
