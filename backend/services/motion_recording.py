"""Recording sensors together while something moves through their views: the input of a time offset.

Lining two sensors' clocks up (:mod:`backend.calib.time_offset`) needs both to watch one motion continuously, a
board carried through both views or the rig turned in a static scene, not the few still captures the other steps
take. :func:`record_motion` reads every named sensor's device on its own stream (:class:`MotionRecorder`, at most
:data:`MAX_HZ` samples a second) and stores every sample as it comes: a camera's frame with its board (frames
without the board are counted, not stored), a LiDAR's scan. The board is found by the live detector
(:func:`~backend.services.live_capture.preview_detector`), whose corners end where the accurate detector's do (the
same refinement at full resolution): the accurate search takes 0.4-0.8 s a 720p frame, which would cap a recording
at about two frames a second, fewer on a busy machine. A lost device ends the recording with its message; what was
stored is kept. Every capture of one recording carries its name in ``meta["recording"]``
(:data:`~backend.store.schema.RECORDING_META_KEY`), so the offset is measured from that recording alone: the session
holds the same sensors' other captures, taken with the board held still, which show no motion to line up.
"""

from __future__ import annotations

import dataclasses
import shutil
import threading
import time
from collections.abc import Sequence

from backend.calib._session import session_board, store_cloud
from backend.calib.intrinsics import service as intrinsics_service
from backend.core.errors import InputError
from backend.core.result import ProgressCallback, no_progress
from backend.devices.base import Sample
from backend.services.live_capture import preview_detector
from backend.services.sensor_stream import SensorStream, StatusCallback
from backend.store.schema import RECORDING_META_KEY
from backend.store.session import Session

RECORDED_KINDS = ("camera", "lidar3d", "lidar2d")
MAX_HZ = 15.0
"""Most samples stored per second and sensor: a carried board turns little in 1/15 s."""
MAX_DURATION_S = 60.0
"""Longest recording (s): 60 s at 15 Hz is 900 captures a sensor, about 250 MB of the demo's 720p images and 400 MB
of its 16-beam scans (10 s took 41 and 70 MB); lining clocks up needs 10-20 s of motion."""
BYTES_PER_SAMPLE = 1_000_000
"""Disk a stored sample may take, at most about (bytes): a 720p PNG is 0.4 MB, a 16-beam scan 0.44 MB, a 1080p
frame or a 128-beam scan about 1 MB."""
OPEN_TIMEOUT_S = 60.0
"""Longest wait (s) for every device's first sample before the recording's clock starts."""
MIN_RATE_HZ = 5.0
"""Fewest captures a second and sensor a board carried at a walking pace, turned to and fro, is followed by: a
recording slower than this (a busy machine, a slow device) is said to be, and the offset's sigma shows the cost."""
PROGRESS_PERIOD_S = 0.25
"""How often the recording's progress is reported (s)."""


@dataclasses.dataclass
class Recording:
    """What one recording stored."""

    name: str
    stored: dict[str, int]
    """Captures stored per sensor."""
    missed: dict[str, int]
    """Camera frames per camera where the board was not found (not stored)."""
    duration_s: float
    rates_hz: dict[str, float]
    """Captures stored a second per sensor over the recording's duration."""

    def slow(self) -> list[str]:
        """The sensors stored at fewer than :data:`MIN_RATE_HZ` captures a second."""
        return [sensor for sensor, rate in self.rates_hz.items() if rate < MIN_RATE_HZ]


class MotionRecorder(SensorStream):
    """Stores every sample of one sensor's stream under one recording's name."""

    kept_phrase = "capture(s)"

    def __init__(self, session: Session, sensor: str, recording: str, status: StatusCallback):
        super().__init__(session, sensor, status, MAX_HZ)
        self.recording = recording
        self.is_camera = session.rig.get(sensor).kind == "camera"
        self.detect = preview_detector(session_board(session)) if self.is_camera else None
        self.stored = 0
        self.missed = 0

    def handle(self, sample: Sample) -> None:
        meta = {**sample.storable_meta(), RECORDING_META_KEY: self.recording}
        try:
            if self.is_camera:
                detection = self.detect(sample.image)
                if detection is None:
                    self.missed += 1
                    return
                intrinsics_service.store_capture(self.session, self.sensor, sample.image, detection,
                                                 device=self.device_name, timestamp_s=sample.timestamp_s, meta=meta)
            else:
                store_cloud(self.session, self.sensor, dataclasses.replace(sample, meta=meta), device=self.device_name)
        except InputError as exc:
            self.status(f"{self.sensor}: {exc.message}", True)
            return
        self.stored += 1


def recordings(session: Session, sensor: str) -> list[str]:
    """The names of the recordings holding captures of ``sensor``, newest first."""
    names = {c.meta[RECORDING_META_KEY]: c.timestamp_s for c in session.captures(sensor)
             if RECORDING_META_KEY in c.meta}
    return sorted(names, key=names.get, reverse=True)


def check_recording(session: Session, sensors: Sequence[str], duration_s: float) -> None:
    """:class:`InputError` (404 for a sensor the rig lacks) unless ``sensors`` can be recorded for ``duration_s``."""
    if not 0 < duration_s <= MAX_DURATION_S:
        raise InputError(f"duration_s {duration_s:g}: expected above 0 and at most {MAX_DURATION_S:g} s", "duration_s")
    if len(set(sensors)) != len(sensors) or not sensors:
        raise InputError(f"sensors {list(sensors)}: expected one or more different sensors", "sensors")
    for sensor in sensors:
        frame = session.rig.get(sensor)
        if frame.kind not in RECORDED_KINDS:
            raise InputError(f"{sensor} ({frame.kind}): recordings hold {', '.join(RECORDED_KINDS)} sensors (an "
                             "IMU is recorded in step 10)", sensor)
        if not frame.device:
            raise InputError(f"{sensor} has no capture device: set one in the sensors step", sensor)
    needed = duration_s * MAX_HZ * len(sensors) * BYTES_PER_SAMPLE
    free = shutil.disk_usage(session.path).free
    if free < needed:
        raise InputError(f"recording {len(sensors)} sensor(s) for {duration_s:g} s may take {needed / 1e9:.1f} GB "
                         f"but the session's disk has {free / 1e9:.1f} GB free: record for less, or free space first",
                         "duration_s")


def record_motion(session: Session, sensors: Sequence[str], duration_s: float,
                  progress: ProgressCallback = no_progress) -> Recording:
    """Record ``sensors`` together for ``duration_s`` seconds, from the moment every device has sent its first
    sample; :class:`InputError` for bad settings or a device that fails (naming it; what was stored is kept)."""
    check_recording(session, sensors, duration_s)
    name = f"rec-{time.strftime('%Y%m%d-%H%M%S')}"
    failed = threading.Event()
    errors: list[str] = []

    def status(message: str, error: bool) -> None:
        if error:
            errors.append(message)
            failed.set()

    streams = [MotionRecorder(session, sensor, name, status) for sensor in sensors]
    for stream in streams:
        stream.start()
    try:
        waited = time.monotonic()
        while not all(stream.frames_seen for stream in streams) and time.monotonic() - waited < OPEN_TIMEOUT_S:
            progress(0.0, "opening " + ", ".join(s.sensor for s in streams if not s.frames_seen))
            if failed.wait(PROGRESS_PERIOD_S):
                break
        silent = [stream.sensor for stream in streams if not stream.frames_seen]
        if silent and not errors:
            errors.append(f"{', '.join(silent)} sent nothing within {OPEN_TIMEOUT_S:g} s")
        started, stored_before = time.monotonic(), {s.sensor: s.stored for s in streams}
        while not errors and (elapsed := time.monotonic() - started) < duration_s:
            progress(elapsed / duration_s, f"recording {name}: " + ", ".join(
                f"{s.sensor} {s.stored} ({s.rate_hz:.0f}/s)" + (f", {s.missed} without the board" if s.missed else "")
                for s in streams))
            failed.wait(min(PROGRESS_PERIOD_S, max(0.0, duration_s - elapsed)))
    finally:
        for stream in streams:
            stream.stop()
    if errors:
        raise InputError(f"recording {name} stopped: {errors[0]}; the captures it stored are kept", name)
    return Recording(name, {s.sensor: s.stored for s in streams}, {s.sensor: s.missed for s in streams if s.is_camera},
                     duration_s, {s.sensor: (s.stored - stored_before[s.sensor]) / duration_s for s in streams})
