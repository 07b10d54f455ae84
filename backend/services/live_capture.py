"""Live camera capture with guidance: detect on every frame, keep frames that add coverage.

Runs the device in its own thread so the UI never waits on a camera. Every frame
is detected quickly for the preview; a frame that adds coverage (see
:mod:`backend.solvers.coverage`) is re-detected at full accuracy and stored as a
capture, immediately and atomically, so an unplugged camera loses nothing.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from backend.core.boards import BoardSpec
from backend.core.errors import InputError
from backend.devices.base import CaptureDevice, DeviceDisconnected, DeviceError, create_device
from backend.services import intrinsics as intrinsics_service
from backend.solvers.board_detection import Detection, detect_board
from backend.solvers.coverage import Coverage
from backend.store.schema import CaptureRecord
from backend.store.session import Session


def coverage_from_captures(session: Session, sensor: str, board: BoardSpec) -> Coverage | None:
    """Coverage of the views already captured for ``sensor`` (None if there are none)."""
    coverage = None
    for capture in session.captures(sensor):
        if capture.detection:
            detection = Detection.from_dict(capture.detection)
            coverage = coverage or Coverage(board, detection.image_size)
            coverage.add(detection)
    return coverage


@dataclass
class LiveCallbacks:
    """What the capture thread reports; each runs on the capture thread."""

    frame: Callable[[np.ndarray, Detection | None, Coverage | None], None]
    captured: Callable[[CaptureRecord, Coverage], None]
    status: Callable[[str, bool], None]
    """(message, is_error)."""


class LiveCapture:
    """One camera's live preview and (auto-)capture loop."""

    def __init__(self, session: Session, sensor: str, callbacks: LiveCallbacks, *, auto_capture: bool = True,
                 max_preview_hz: float = 15.0):
        self.session = session
        self.sensor = sensor
        self.board = intrinsics_service.session_board(session)
        self.callbacks = callbacks
        self.auto_capture = auto_capture
        self.coverage = coverage_from_captures(session, sensor, self.board)
        self._min_period_s = 1.0 / max_preview_hz
        self._stop = threading.Event()
        self._capture_next = threading.Event()
        self._thread: threading.Thread | None = None
        self.frames_seen = 0

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name=f"live-{self.sensor}", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)

    def capture_now(self) -> None:
        """Keep the next frame with a board, whether or not it adds coverage."""
        self._capture_next.set()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _open(self) -> CaptureDevice:
        settings = self.session.rig.get(self.sensor).device
        if not settings:
            raise DeviceError("no capture device configured for this sensor; set one in the sensors step",
                              self.sensor)
        device = create_device(settings)
        device.open()
        return device

    def _run(self) -> None:
        try:
            device = self._open()
        except DeviceError as exc:
            self.callbacks.status(str(exc), True)
            return
        self.callbacks.status(f"live: {device.describe()}", False)
        try:
            while not self._stop.is_set():
                started = time.perf_counter()
                try:
                    sample = device.read()
                except InputError as exc:  # one corrupt frame (e.g. a bad file in a folder): skip it
                    self.callbacks.status(exc.message, True)
                    continue
                self.frames_seen += 1
                self._handle(sample.image, sample.timestamp_s, device.describe(), sample.meta)
                time.sleep(max(0.0, self._min_period_s - (time.perf_counter() - started)))
        except DeviceDisconnected as exc:
            kept = len(self.session.captures(self.sensor))
            self.callbacks.status(f"{exc} - the {kept} capture(s) taken so far are kept", True)
        finally:
            device.close()

    def _handle(self, image: np.ndarray, timestamp_s: float, device_name: str, meta: dict) -> None:
        detection = detect_board(image, self.board, live=True)
        wanted = self._capture_next.is_set() or (
            self.auto_capture and detection is not None
            and (self.coverage is None or self.coverage.adds_coverage(detection)))
        if detection is not None and wanted:
            detection = detect_board(image, self.board)  # full accuracy for what is kept
        if detection is not None and wanted:
            self._capture_next.clear()
            meta = {k: v for k, v in meta.items() if isinstance(v, (int, float, str, bool, list))}
            try:
                record = intrinsics_service.store_capture(self.session, self.sensor, image, detection,
                                                          device=device_name, timestamp_s=timestamp_s, meta=meta)
            except InputError as exc:
                self.callbacks.status(exc.message, True)
            else:
                self.coverage = self.coverage or Coverage(self.board, detection.image_size)
                self.coverage.add(detection)
                self.callbacks.captured(record, self.coverage)
        self.callbacks.frame(image, detection, self.coverage)
