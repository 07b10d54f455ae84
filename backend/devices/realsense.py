"""Intel RealSense depth cameras through librealsense (driver ``"realsense"``, optional extra ``realsense``).

``pyrealsense2`` (``pip install 'calib-studio[realsense]'``, a wheel with librealsense inside) is imported only in
:meth:`RealSenseCamera.open`, so everything else works without it.

The depth stream (``z16``: 16-bit units of the device's ``depth_scale`` metres, 0 = no return) becomes metres; the
first infrared stream (``y8``, the imager the depth is computed in, so pixel for pixel aligned with it) gives the
amplitude; the depth stream profile's intrinsics (fx, fy, ppx, ppy in px, pixel centres as in OpenCV) give the
pinhole. The D400 and L500 depth streams are rectified (their distortion coefficients are all zero); a stream
that reports non-zero coefficients is refused rather than unprojected wrongly. The conversions are pure functions
(:func:`realsense_camera`, :func:`realsense_frame_to_sample`).
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from backend.core.camera import CameraIntrinsics
from backend.devices.base import CaptureDevice, DeviceDisconnected, DeviceError, Sample, register_driver
from backend.devices.depth_files import check_ranges, depth_sample, pinhole_of

log = logging.getLogger(__name__)

MISSING_MESSAGE = "pyrealsense2 is not installed: pip install 'calib-studio[realsense]'"


def realsense_camera(intrinsics: Any, device: str = "realsense") -> CameraIntrinsics:
    """The depth camera of a librealsense ``intrinsics`` (any object with ``width, height, fx, fy, ppx, ppy`` in px,
    ``model`` and ``coeffs``); :class:`DeviceError` naming ``device`` for a stream with lens distortion."""
    coeffs = [float(c) for c in intrinsics.coeffs]
    if any(coeffs):
        model = getattr(intrinsics.model, "name", str(intrinsics.model))
        raise DeviceError(f"the depth stream reports {model} distortion {coeffs}; only rectified depth streams "
                          "(all coefficients zero, as on the D400 and L500) are supported", device)
    K = np.array([[float(intrinsics.fx), 0.0, float(intrinsics.ppx)], [0.0, float(intrinsics.fy),
                                                                        float(intrinsics.ppy)], [0.0, 0.0, 1.0]])
    return CameraIntrinsics("pinhole-radtan", int(intrinsics.width), int(intrinsics.height), K)


def realsense_frame_to_sample(z16: np.ndarray, depth_scale_m: float, infrared: np.ndarray | None,
                              camera: CameraIntrinsics, timestamp_s: float, min_range_m: float = 0.3,
                              max_range_m: float = 6.0, meta: dict[str, Any] | None = None,
                              source: str = "realsense") -> Sample:
    """The depth :class:`Sample` of one frame set: ``z16`` (H, W uint16 depth units), ``depth_scale_m`` (m per
    unit), ``infrared`` (H, W y8/y16 amplitude, or None) and ``camera`` from :func:`realsense_camera`."""
    depth = np.asarray(z16, dtype=np.uint16).astype(np.float32) * np.float32(depth_scale_m)
    amplitude = None if infrared is None else np.asarray(infrared, dtype=np.float32)
    return depth_sample(depth, pinhole_of(camera, min_range_m, max_range_m), timestamp_s, source, amplitude,
                        {"depth_scale_m": float(depth_scale_m), **(meta or {})})


@register_driver
class RealSenseCamera(CaptureDevice):
    """A RealSense depth camera (D400 series, L515) as depth samples (see the module docs).

    ``serial`` picks one of several cameras (default: the first found); ``width`` x ``height`` at ``fps`` is the
    depth (and infrared) stream mode the camera must offer (848x480 at 30 Hz suits every D400);
    ``infrared`` adds the amplitude. ``timeout_s``: how long :meth:`read` waits before it reports the camera
    gone. ``min_range_m`` / ``max_range_m`` (m) bound the depth unprojected into points. Samples carry the read
    time as ``timestamp_s`` and meta ``serial``, ``device_timestamp_ms`` (the camera's clock) and ``frame_number``.
    """

    driver = "realsense"

    def __init__(self, serial: str | None = None, width: int = 848, height: int = 480, fps: int = 30,
                 infrared: bool = True, timeout_s: float = 2.0, min_range_m: float = 0.3, max_range_m: float = 6.0):
        self.serial = None if serial in (None, "") else str(serial)
        self.name = f"realsense {self.serial or '(first found)'}"
        for key, value, low, high in (("width", width, 1, 4096), ("height", height, 1, 4096), ("fps", fps, 1, 300)):
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                raise DeviceError(f"{key} must be an integer from {low} to {high}, got {value!r}", self.name)
        if isinstance(timeout_s, bool) or not isinstance(timeout_s, int | float) or not 0 < timeout_s < 60:
            raise DeviceError(f"timeout_s must be seconds between 0 and 60, got {timeout_s!r}", self.name)
        self.width, self.height, self.fps = width, height, fps
        self.infrared = bool(infrared)
        self.timeout_s = float(timeout_s)
        self.min_range_m, self.max_range_m = check_ranges(min_range_m, max_range_m, self.name)
        self.camera: CameraIntrinsics | None = None
        """The depth stream's pinhole (known once open)."""
        self.depth_scale_m: float | None = None
        """Metres per depth unit (known once open)."""
        self._pipeline: Any = None

    def open(self) -> None:
        """Start the depth (and infrared) streams; :class:`DeviceError` saying why they cannot start."""
        self.close()
        try:
            import pyrealsense2 as rs
        except ImportError:
            raise DeviceError(MISSING_MESSAGE, self.name) from None
        config = rs.config()
        if self.serial is not None:
            config.enable_device(self.serial)
        config.enable_stream(rs.stream.depth, self.width, self.height, rs.format.z16, self.fps)
        if self.infrared:
            config.enable_stream(rs.stream.infrared, 1, self.width, self.height, rs.format.y8, self.fps)
        pipeline = rs.pipeline()
        try:
            profile = pipeline.start(config)
        except RuntimeError as exc:  # librealsense says why: no device, a mode it does not offer, busy...
            raise DeviceError(f"cannot start {self.width}x{self.height} depth at {self.fps} Hz: {exc}",
                              self.name) from None
        try:
            device = profile.get_device()
            self.depth_scale_m = float(device.first_depth_sensor().get_depth_scale())
            stream = profile.get_stream(rs.stream.depth).as_video_stream_profile()
            self.camera = realsense_camera(stream.get_intrinsics(), self.name)
            self.serial = str(device.get_info(rs.camera_info.serial_number))
        except BaseException:
            pipeline.stop()
            raise
        self._pipeline = pipeline
        self.name = f"realsense {self.serial}"

    def read(self) -> Sample:
        """The next frame set; :class:`DeviceDisconnected` when none comes within ``timeout_s``."""
        if self._pipeline is None or self.camera is None or self.depth_scale_m is None:
            raise DeviceError("not open; call open() first", self.name)
        ok, frames = self._pipeline.try_wait_for_frames(int(self.timeout_s * 1000))
        if not ok:
            raise DeviceDisconnected(f"no frame within {self.timeout_s:g} s (unplugged?)", self.name)
        depth_frame = frames.get_depth_frame()
        z16 = np.array(depth_frame.get_data(), dtype=np.uint16)  # copies: the frame goes back to librealsense
        infrared = np.array(frames.get_infrared_frame(1).get_data()) if self.infrared else None
        meta = {"serial": self.serial, "device_timestamp_ms": float(depth_frame.get_timestamp()),
                "frame_number": int(depth_frame.get_frame_number())}
        return realsense_frame_to_sample(z16, self.depth_scale_m, infrared, self.camera, time.time(),
                                         self.min_range_m, self.max_range_m, meta, self.name)

    def close(self) -> None:
        """Stop the streams; safe to call twice."""
        pipeline, self._pipeline = self._pipeline, None
        if pipeline is not None:
            try:
                pipeline.stop()
            except RuntimeError as exc:  # an unplugged camera fails to stop; it is gone either way
                log.warning("%s: stopping failed: %s", self.name, exc)

    def describe(self) -> str:
        return f"{self.name} {self.width}x{self.height} at {self.fps} Hz"
