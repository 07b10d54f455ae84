"""USB (UVC) cameras through OpenCV's ``VideoCapture`` (driver ``"uvc"``).

``device`` is a camera index (``0`` is ``/dev/video0`` on Linux), a device path
such as ``/dev/video2``, or anything else OpenCV opens: a video file or a stream
URL. Files and URLs go through the same code path, which is how the driver is
tested without hardware: the end of a file looks exactly like an unplugged camera.
"""

from __future__ import annotations

import logging
import os
import sys
import time

import cv2
import numpy as np

from backend.devices.base import CaptureDevice, DeviceDisconnected, DeviceError, Sample, register_driver

log = logging.getLogger(__name__)

_RETRY_DELAY_S = 0.02
"""Pause between retries of a failed read, to ride over a single dropped frame."""


def _is_local_device(device: int | str) -> bool:
    return isinstance(device, int) or str(device).startswith("/dev/")


@register_driver
class UvcCamera(CaptureDevice):
    """A UVC camera (or video file / stream URL) read frame by frame.

    A ``device`` string of digits (as a settings form may send) means that index.

    ``width``/``height``/``fps``/``fourcc`` are requests: the camera may pick
    something else. After :meth:`open`, :attr:`actual_size` holds what it gave
    and :meth:`describe` warns when that differs from the request. ``fourcc``
    defaults to ``"MJPG"``, which most UVC cameras need for high resolutions
    at full frame rate; ``None`` keeps the camera's default.

    A failed read is retried up to ``max_failed_reads`` consecutive times before
    :class:`DeviceDisconnected` is raised. Samples carry a BGR image, the read
    time (``time.time()``) and meta ``{"frame_index", "device"}``.
    """

    driver = "uvc"

    def __init__(
        self,
        device: int | str = 0,
        width: int | None = None,
        height: int | None = None,
        fps: float | None = None,
        fourcc: str | None = "MJPG",
        max_failed_reads: int = 5,
    ):
        if fourcc is not None and len(fourcc) != 4:
            raise DeviceError(f"fourcc must be 4 characters like 'MJPG' or 'YUYV', got {fourcc!r}", str(device))
        if max_failed_reads < 1:
            raise DeviceError(f"max_failed_reads must be at least 1, got {max_failed_reads}", str(device))
        self.device: int | str = int(device) if isinstance(device, str) and device.isdigit() else device
        self.width = width
        self.height = height
        self.fps = fps
        self.fourcc = fourcc
        self.max_failed_reads = max_failed_reads
        linux_index = isinstance(self.device, int) and sys.platform.startswith("linux")
        self.name = f"/dev/video{self.device}" if linux_index else str(self.device)
        """The device as shown in messages, e.g. ``/dev/video0``."""
        self._cap: cv2.VideoCapture | None = None
        self._frames = 0
        self._actual_size: tuple[int, int] | None = None

    @property
    def actual_size(self) -> tuple[int, int] | None:
        """``(width, height)`` the camera delivers (``None`` before :meth:`open`)."""
        return self._actual_size

    @property
    def size_warning(self) -> str | None:
        """Why the delivered resolution is not the requested one, or ``None`` if it is."""
        if self._actual_size is None or (self.width is None and self.height is None):
            return None
        width, height = self._actual_size
        if (self.width or width, self.height or height) == (width, height):
            return None
        return f"asked {self.width or '?'}x{self.height or '?'} but the camera gives {width}x{height}"

    def open(self) -> None:
        """Open and configure the camera; raise :class:`DeviceError` saying why if it fails."""
        self.close()
        if _is_local_device(self.device) and sys.platform.startswith("linux"):
            cap = cv2.VideoCapture(self.device, cv2.CAP_V4L2)
        else:
            cap = cv2.VideoCapture(self.device, cv2.CAP_ANY)
        if not cap.isOpened():
            cap.release()
            raise DeviceError(self._open_failure(), self.name)
        if self.fourcc is not None:
            cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*self.fourcc))
        if self.width is not None:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
        if self.height is not None:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        if self.fps is not None:
            cap.set(cv2.CAP_PROP_FPS, self.fps)
        width, height = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        self._actual_size = (width, height) if width > 0 and height > 0 else None
        self._cap = cap
        self._frames = 0
        if self.size_warning:
            log.warning("%s: %s", self.name, self.size_warning)

    def read(self) -> Sample:
        """Grab and return the next frame.

        Raises :class:`DeviceDisconnected` after ``max_failed_reads`` consecutive failed reads.
        """
        if self._cap is None:
            raise DeviceError("not open; call open() first", self.name)
        for attempt in range(self.max_failed_reads):
            if attempt:
                time.sleep(_RETRY_DELAY_S)
            if not self._cap.grab():
                continue
            ok, frame = self._cap.retrieve()
            if ok and frame is not None and frame.size:
                return self._sample(frame)
        raise DeviceDisconnected(
            f"camera stopped delivering frames (unplugged?) after {self._frames} frames", self.name
        )

    def close(self) -> None:
        """Release the camera; safe to call twice."""
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def describe(self) -> str:
        size = f" {self._actual_size[0]}x{self._actual_size[1]}" if self._actual_size else ""
        warning = f" (warning: {self.size_warning})" if self.size_warning else ""
        return f"{self.driver} {self.name}{size}{warning}"

    def _sample(self, frame: np.ndarray) -> Sample:
        """Wrap a retrieved frame, converting gray/BGRA to BGR and recording the delivered size."""
        if frame.ndim == 2:
            frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
        elif frame.shape[2] == 4:
            frame = cv2.cvtColor(frame, cv2.COLOR_BGRA2BGR)
        self._actual_size = (frame.shape[1], frame.shape[0])
        sample = Sample(timestamp_s=time.time(), image=frame, meta={"frame_index": self._frames, "device": self.name})
        self._frames += 1
        return sample

    def _open_failure(self) -> str:
        """The message for a camera that would not open, with the likely reason and a hint."""
        if _is_local_device(self.device):
            missing = self.name.startswith("/dev/") and not os.path.exists(self.name)
            reason = "no such device" if missing else "the device is busy or not a camera"
            hint = "is it plugged in and not used by another program?"
        elif "://" not in str(self.device) and not os.path.exists(str(self.device)):
            reason, hint = "no such file", "check the path"
        else:
            reason, hint = "OpenCV cannot read it", "check the URL or file and that its format is supported"
        return f"could not open camera {self.name}: {reason} — {hint}"
