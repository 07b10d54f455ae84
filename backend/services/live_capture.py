"""Live camera capture with guidance: detect on every frame, keep frames that add coverage.

Runs the device in its own thread so the UI never waits on a camera. Every frame
is detected quickly for the preview (:mod:`backend.calib.board.live_detection`) and the board posed in the
camera's frame (PnP, on this thread, so the UI only draws); a frame that adds coverage (see
:mod:`backend.calib.board.coverage`) is re-detected at full accuracy and stored as a
capture, immediately and atomically, so an unplugged camera loses nothing.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from backend.calib._session import session_board
from backend.calib.board.coverage import PARAM_NAMES, Coverage, enough_data
from backend.calib.board.detection import Detection
from backend.calib.board.live_detection import LiveDetector
from backend.calib.board.pose import board_pose, nominal_camera
from backend.calib.intrinsics import service as intrinsics_service
from backend.calib.test_field.detection import detect_target, detect_test_field
from backend.core.boards import BoardSpec
from backend.core.errors import InputError
from backend.core.targets import CameraTarget
from backend.devices.base import Sample
from backend.services.sensor_stream import SensorStream
from backend.store.schema import CaptureRecord
from backend.store.session import Session


def coverage_from_captures(session: Session, sensor: str, board: BoardSpec) -> Coverage | None:
    """Coverage of the lens views already captured for ``sensor`` (None if there are none;
    :func:`~backend.calib.intrinsics.service.is_lens_view`)."""
    coverage = None
    target = intrinsics_service.target_identity(session)
    for capture in session.captures(sensor):
        if intrinsics_service.is_lens_view(capture, target):
            detection = Detection.from_dict(capture.detection)
            coverage = coverage or Coverage(board, detection.image_size)
            coverage.add(detection)
    return coverage


__all__ = ["PARAM_NAMES", "Coverage", "LiveCallbacks", "LiveCapture", "LiveFrame", "coverage_from_captures",
           "data_enough", "last_capture", "worth_keeping"]


def data_enough(session: Session, sensor: str, coverage: Coverage) -> tuple[bool, list[str]]:
    """Whether ``coverage`` and the latest intrinsics solve of ``sensor`` together make enough data, and what
    is missing if not (:func:`backend.calib.board.coverage.enough_data`). A solve counts only while it was made
    from the views now kept (every lens view): after views are added (or removed) its projection
    sigma no longer says how far these views can be trusted, and a solve is asked for again."""
    latest = session.results(sensor, "intrinsics")[-1:]
    target = intrinsics_service.target_identity(session)
    views = {capture.id for capture in session.captures(sensor) if intrinsics_service.is_lens_view(capture, target)}
    current = bool(latest) and set(latest[0].get("inputs") or ()) == views
    return enough_data(coverage, latest[0]["projection_uncertainty"] if current else None)


def worth_keeping(coverage: Coverage | None, detection: Detection | None) -> bool:
    """Whether auto-capture keeps a frame whose live detection is ``detection``, given the ``coverage`` of the views
    kept so far (None before the first): the board is seen and adds coverage (:meth:`Coverage.adds_coverage`)."""
    return detection is not None and (coverage is None or coverage.adds_coverage(detection))


def last_capture(session: Session, sensor: str) -> tuple[np.ndarray, Detection | None] | None:
    """The image of ``sensor``'s latest capture and its board detection (None without captures)."""
    captures = session.captures(sensor)
    if not captures:
        return None
    last = captures[-1]
    return session.capture_image(sensor, last.id), Detection.from_dict(last.detection) if last.detection else None


@dataclass
class LiveFrame:
    """One live frame as the preview shows it."""

    image: np.ndarray
    """The camera's image (uint8, gray or BGR)."""
    detection: Detection | None
    """The board's corners in it, if found."""
    coverage: Coverage | None
    """The coverage of the views kept so far (None before the first)."""
    T_camera_board: np.ndarray | None
    """4x4 (m) board pose in the camera's optical frame by PnP (the camera's intrinsics, or a nominal pinhole
    before it has any); None without a detection or when PnP fails."""


@dataclass
class LiveCallbacks:
    """What the capture thread reports; each runs on the capture thread."""

    frame: Callable[[LiveFrame], None]
    captured: Callable[[CaptureRecord, Coverage], None]
    status: Callable[[str, bool], None]
    """(message, is_error)."""


def preview_detector(board: CameraTarget) -> Callable[[np.ndarray], Detection | None]:
    """The fast detection a live preview runs on every frame: a board's at reduced resolution
    (:class:`LiveDetector`); a test field's markers as they are (the marker search is fast at full size)."""
    if isinstance(board, BoardSpec):
        return LiveDetector(board).detect
    return lambda image: detect_test_field(image, board, "frame").detection


class LiveCapture(SensorStream):
    """One camera's live preview and (auto-)capture loop."""

    kept_phrase = "capture(s) taken"

    def __init__(self, session: Session, sensor: str, callbacks: LiveCallbacks, *, auto_capture: bool = True,
                 max_preview_hz: float = 15.0):
        super().__init__(session, sensor, callbacks.status, max_preview_hz)
        self.board = session_board(session)
        self.callbacks = callbacks
        self.auto_capture = auto_capture
        self.coverage = coverage_from_captures(session, sensor, self.board)
        self._capture_next = threading.Event()
        self._preview_detection = preview_detector(self.board)

    def capture_now(self) -> None:
        """Keep the next frame with a board, whether or not it adds coverage."""
        self._capture_next.set()

    def handle(self, sample: Sample) -> None:
        image = sample.image
        detection = self._preview_detection(image)  # fast, for the preview
        wanted = self._capture_next.is_set() or (self.auto_capture and worth_keeping(self.coverage, detection))
        if detection is not None and wanted:
            detection = detect_target(image, self.board, "frame")[0]  # full accuracy for what is kept
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
        self.callbacks.frame(LiveFrame(image, detection, self.coverage, self._board_pose(detection)))

    def _board_pose(self, detection: Detection | None) -> np.ndarray | None:
        if detection is None:
            return None
        camera = self.session.rig.get(self.sensor).intrinsics or nominal_camera(*detection.image_size)
        return board_pose(camera, self.board, detection)
