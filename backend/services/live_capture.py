"""Live camera capture with guidance: detect on every frame, keep frames that add coverage.

Runs the device in its own thread so the UI never waits on a camera. Every frame
is detected quickly for the preview (:mod:`backend.calib.board.live_detection`); a frame that adds coverage (see
:mod:`backend.calib.board.coverage`) is re-detected at full accuracy and stored as a
capture, immediately and atomically, so an unplugged camera loses nothing.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from backend.calib.board.coverage import Coverage
from backend.calib.board.detection import Detection, detect_board
from backend.calib.board.live_detection import LiveDetector
from backend.calib.intrinsics import service as intrinsics_service
from backend.core.boards import BoardSpec
from backend.core.errors import InputError
from backend.devices.base import Sample
from backend.services.sensor_stream import SensorStream
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


class LiveCapture(SensorStream):
    """One camera's live preview and (auto-)capture loop."""

    kept_phrase = "capture(s) taken"

    def __init__(self, session: Session, sensor: str, callbacks: LiveCallbacks, *, auto_capture: bool = True,
                 max_preview_hz: float = 15.0):
        super().__init__(session, sensor, callbacks.status, max_preview_hz)
        self.board = intrinsics_service.session_board(session)
        self.callbacks = callbacks
        self.auto_capture = auto_capture
        self.coverage = coverage_from_captures(session, sensor, self.board)
        self._capture_next = threading.Event()
        self._detector = LiveDetector(self.board)

    def capture_now(self) -> None:
        """Keep the next frame with a board, whether or not it adds coverage."""
        self._capture_next.set()

    def handle(self, sample: Sample) -> None:
        image = sample.image
        detection = self._detector.detect(image)  # fast, for the preview
        wanted = self._capture_next.is_set() or (
            self.auto_capture and detection is not None
            and (self.coverage is None or self.coverage.adds_coverage(detection)))
        if detection is not None and wanted:
            detection = detect_board(image, self.board)  # full accuracy for what is kept
        if detection is not None and wanted:
            self._capture_next.clear()
            try:
                record = intrinsics_service.store_capture(self.session, self.sensor, image, detection,
                                                          device=self.device_name, timestamp_s=sample.timestamp_s,
                                                          meta=sample.storable_meta())
            except InputError as exc:
                self.callbacks.status(exc.message, True)
            else:
                self.coverage = self.coverage or Coverage(self.board, detection.image_size)
                self.coverage.add(detection)
                self.callbacks.captured(record, self.coverage)
        self.callbacks.frame(image, detection, self.coverage)
