"""Synchronised image sets for joint multi-camera calibration: captured live, imported from a bag, listed.

Data model (the multi-camera solver reads it)
---------------------------------------------
A *set* is one moment seen by several cameras: one ordinary image capture per camera,
stored like an intrinsics capture (:func:`backend.calib.intrinsics.service.store_capture`, with
the board detection, or None where that camera did not see the board). Each capture of a
set carries in ``meta``:

* ``multicam_set``: the set's name, ``"set00007"``; unique in the session and increasing in
  the order sets are stored (a refused or failed set may leave a gap);
* ``multicam_cameras``: the names of every camera of the set, in the order they were given;
* ``multicam_stamp_s``: the frame's capture time on the rig's clock (s): its stamp (the header stamp for a bag) less
  the camera's ``clock_offset_s`` (:meth:`~backend.core.rig.Frame.rig_time`);
* ``clock_offset_s``: the camera's clock offset this set assumed (s; 0 until a time offset is accepted).

Captures are written one after the other, so a set is *stored* only when every camera in
``multicam_cameras`` holds a capture with its name; :func:`stored_sets` ignores the
captures of a set that a failure cut short. Everything that can be checked (frame times,
image sizes, board views, the bag and its topics) is checked before the first capture of
a set is written, so only a failing disk can leave such a remnant. A set is useful to a
solver when at least two of its cameras see the board.

Matching by time (:func:`match_by_timestamp`), live and from a bag, works on the rig's
clock (each camera's stamps less its accepted clock offset) and is greedy over the
sorted union of all stamps: the earliest frame not yet used anchors a set, and every
other camera joins with its earliest unused frame no later than ``tolerance_s`` after
the anchor, so all frames of a set lie within ``tolerance_s`` of each other. An anchor
no other camera joins is left unmatched. This is unambiguous when ``tolerance_s`` is
well under half the frame period.
"""

from __future__ import annotations

import contextlib
import os
import re
import threading
import weakref
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from backend.calib._session import check_camera, session_plane_board
from backend.calib.board.detection import Detection, detect_board
from backend.calib.intrinsics import service as intrinsics_service
from backend.calib.lidar_camera.capture import check_image_size
from backend.core.boards import BoardSpec
from backend.core.errors import CancelledError, InputError
from backend.core.result import ProgressCallback, no_progress
from backend.devices.base import CaptureDevice, DeviceDisconnected, DeviceError, Sample, create_device
from backend.devices.rosbag_source import COMPRESSED_IMAGE, IMAGE, RosbagError, RosbagSource
from backend.store.schema import CaptureRecord
from backend.store.session import Session

DEFAULT_TOLERANCE_S = 0.02
"""Largest spread (s) of the frame times within one set."""
MIN_BOARD_VIEWS = 2
READ_ATTEMPTS = 3
"""Reads of all cameras together before frames out of step are refused."""
"""Cameras that must see the board for a set to constrain their relative pose."""
SET_NAME = re.compile(r"set(\d+)")
SCAN_SHARE = 0.3
"""Share of a bag import's progress spent reading the frame times (the rest: detecting and storing)."""

_last_set_number: weakref.WeakKeyDictionary[Session, int] = weakref.WeakKeyDictionary()
"""Highest set number handed out per open session, so sets stored concurrently never share a name."""


@dataclass
class SyncMatch:
    """Frames of several cameras grouped by time (:func:`match_by_timestamp`)."""

    sets: list[dict[str, int]]
    """Per set, in time order: camera -> index of its frame in the stamps given (at least two cameras)."""
    unmatched: dict[str, list[int]]
    """Per camera, the indices (ascending) of its frames that are in no set."""


@dataclass
class MulticamSet:
    """One stored synchronised set: the capture of each camera in it."""

    name: str
    """``"set00007"``, the captures' ``meta["multicam_set"]``."""
    captures: dict[str, CaptureRecord]
    """Camera -> its capture, in the set's camera order."""

    @property
    def cameras(self) -> list[str]:
        return list(self.captures)

    @property
    def cameras_with_board(self) -> list[str]:
        """The cameras whose capture holds a board detection."""
        return [camera for camera, capture in self.captures.items() if capture.detection is not None]


@dataclass
class CameraImport:
    """What a bag import did with one camera's topic."""

    topic: str
    read: int = 0
    """Frames read (in the time window)."""
    matched: int = 0
    """Frames that are in a matched set."""
    unmatched: list[int] = field(default_factory=list)
    """Positions (``#k`` on the topic, 0-based in the window) of frames in no set."""
    stored: int = 0
    """Captures stored (frames of the stored sets)."""
    skipped: list[dict[str, Any]] = field(default_factory=list)
    """``{"message", "input"}`` of each message that could not be converted to an image."""

    def to_dict(self) -> dict[str, Any]:
        return {"topic": self.topic, "read": self.read, "matched": self.matched, "unmatched": len(self.unmatched),
                "unmatched_frames": self.unmatched, "stored": self.stored, "skipped": self.skipped}


@dataclass
class BagImportReport:
    """What :func:`import_bag_sets` did."""

    bag: str
    cameras: dict[str, CameraImport]
    matched_sets: int = 0
    """Sets the frame times gave (before ``every``, ``limit`` and the board check)."""
    sets: list[str] = field(default_factory=list)
    """Names of the sets stored, in time order."""
    no_board: int = 0
    """Sets not stored because fewer than two of their cameras saw the board."""
    ended: str = ""
    """Why the import stopped: the bag's end or the limit."""
    clock_offsets_s: dict[str, float] = field(default_factory=dict)
    """The cameras' clock offsets (s) the matching took off their stamps (the rig's accepted time offsets)."""

    def to_dict(self) -> dict[str, Any]:
        return {"bag": self.bag, "cameras": {name: c.to_dict() for name, c in self.cameras.items()},
                "matched_sets": self.matched_sets, "sets": self.sets, "no_board": self.no_board, "ended": self.ended,
                "clock_offsets_s": self.clock_offsets_s}


# --------------------------------------------------------------------------------------------
# Matching frames by time


def _check_tolerance(tolerance_s: float) -> None:
    if not tolerance_s >= 0:  # also refuses NaN
        raise InputError(f"the time tolerance must be 0 s or more, not {tolerance_s}", "tolerance_s")


def match_by_timestamp(stamps: Mapping[str, Sequence[float]], tolerance_s: float) -> SyncMatch:
    """Group the frames of several cameras into sets of simultaneous frames.

    ``stamps``: camera -> its frame times (s, any order, any common clock). Each set holds
    at most one frame per camera, at least two cameras, and all its frames lie within
    ``tolerance_s`` (s, inclusive) of each other; see the module docs for the greedy rule.
    Ties go to the camera named first.
    """
    cameras = list(stamps)
    if len(cameras) < 2:
        raise InputError(f"matching frames needs at least two cameras, not {len(cameras)}", "cameras")
    _check_tolerance(tolerance_s)
    times = [np.asarray(stamps[camera], dtype=float).ravel() for camera in cameras]
    for camera, t in zip(cameras, times, strict=True):
        if not np.all(np.isfinite(t)):
            raise InputError(f"{camera} has frame times that are not finite numbers", camera)
    orders = [np.argsort(t, kind="stable") for t in times]
    table = np.full((len(cameras), max(len(t) for t in times) + 1), np.inf)  # sorted times, padded with inf
    for row, (t, order) in enumerate(zip(times, orders, strict=True)):
        table[row, :len(t)] = t[order]
    heads = np.zeros(len(cameras), dtype=int)
    rows = np.arange(len(cameras))
    sets: list[dict[str, int]] = []
    unmatched: dict[str, list[int]] = {camera: [] for camera in cameras}
    while True:
        front = table[rows, heads]  # each camera's earliest unused frame time (inf when used up)
        anchor = int(np.argmin(front))
        if not np.isfinite(front[anchor]):
            break
        members = np.flatnonzero(front - front[anchor] <= tolerance_s)
        if len(members) < 2:
            unmatched[cameras[anchor]].append(int(orders[anchor][heads[anchor]]))
            heads[anchor] += 1
            continue
        sets.append({cameras[i]: int(orders[i][heads[i]]) for i in members})
        heads[members] += 1
    return SyncMatch(sets, {camera: sorted(frames) for camera, frames in unmatched.items()})


# --------------------------------------------------------------------------------------------
# Checks made before anything is stored


def _check_cameras(session: Session, cameras: Sequence[str]) -> None:
    if len(cameras) < 2 or len(set(cameras)) != len(cameras):
        raise InputError(f"a synchronised set needs at least two different cameras, not {list(cameras)}", "cameras")
    for camera in cameras:
        check_camera(session, camera)


def _set_board(session: Session, require_board: bool) -> BoardSpec | None:
    """The session's board, or None when it has none and none is required."""
    if session.board or require_board:
        return session_plane_board(session, "the multi-camera rig")
    return None


def _check_spread(stamps: Mapping[str, float], tolerance_s: float) -> None:
    """Refuse frames whose times (s) spread over more than ``tolerance_s``, naming each late camera."""
    first = min(stamps, key=stamps.__getitem__)
    late = {camera: t - stamps[first] for camera, t in stamps.items() if t - stamps[first] > tolerance_s}
    if late:
        details = ", ".join(f"{camera} by {1e3 * dt:.1f} ms" for camera, dt in late.items())
        raise InputError(f"the frames were not taken together: later than {first}'s frame were {details} (tolerance "
                         f"{1e3 * tolerance_s:.1f} ms); no set was stored. Trigger the cameras together or raise "
                         "the tolerance", max(late, key=late.__getitem__))


def _check_image(session: Session, camera: str, image: np.ndarray | None) -> None:
    """Refuse a missing image, or one whose size differs from the camera's intrinsics or earlier captures."""
    if image is None:
        raise InputError(f"{camera}'s device gave no image; no set was stored", camera)
    intrinsics = session.rig.get(camera).intrinsics
    if intrinsics is not None:
        try:
            check_image_size(image, intrinsics, camera)
        except InputError as exc:
            raise InputError(f"{camera}: {exc.message}; no set was stored", camera) from None
    # the check store_capture makes, made here so a set is never half stored
    intrinsics_service.check_size(session, camera, camera, image)


def _detect_all(images: Mapping[str, np.ndarray], board: BoardSpec | None) -> dict[str, Detection | None]:
    """Each camera's board detection (None when not seen or without a board), detected in parallel."""
    if board is None:
        return dict.fromkeys(images)
    with ThreadPoolExecutor(max_workers=min(len(images), os.cpu_count() or 1)) as pool:
        return dict(zip(images, pool.map(lambda image: detect_board(image, board), images.values()), strict=True))


def _views_text(detections: Mapping[str, Detection | None]) -> str:
    seen = [camera for camera, detection in detections.items() if detection is not None]
    return f"{len(seen)} of {len(detections)} cameras ({', '.join(seen) or 'none'})"


def _enough_views(detections: Mapping[str, Detection | None]) -> bool:
    return sum(detection is not None for detection in detections.values()) >= MIN_BOARD_VIEWS


# --------------------------------------------------------------------------------------------
# Storing and listing sets


def _highest_set_number(session: Session) -> int:
    numbers = [0]
    for frame in session.rig.sensors("camera"):
        for capture in session.captures(frame.name):
            match = SET_NAME.fullmatch(str(capture.meta.get("multicam_set", "")))
            if match:
                numbers.append(int(match.group(1)))
    return max(numbers)


def _claim_set_name(session: Session) -> str:
    """A fresh set name, higher than any stored or handed out before in this session."""
    with session.lock:
        number = _last_set_number.get(session)
        number = (_highest_set_number(session) if number is None else number) + 1
        _last_set_number[session] = number
        return f"set{number:05d}"


def _store_set(session: Session, samples: Mapping[str, Sample], detections: Mapping[str, Detection | None], *,
               device: str, sources: Mapping[str, str] | None = None) -> MulticamSet:
    """Store checked samples as one set (no progress reports in between: cancelling never cuts a set short)."""
    with session.lock:
        name = _claim_set_name(session)
        cameras = list(samples)
        captures = {}
        for camera, sample in samples.items():
            frame = session.rig.get(camera)
            meta = {**sample.storable_meta(), "multicam_set": name, "multicam_cameras": cameras,
                    "multicam_stamp_s": frame.rig_time(sample.timestamp_s), "clock_offset_s": frame.clock_offset_s}
            captures[camera] = intrinsics_service.store_capture(
                session, camera, sample.image, detections[camera], device=device, timestamp_s=sample.timestamp_s,
                source=sources[camera] if sources else None, meta=meta)
        return MulticamSet(name, captures)


def stored_sets(session: Session, cameras: list[str] | None = None) -> list[MulticamSet]:
    """The session's complete sets, oldest first.

    With ``cameras``, only the sets holding at least two of them, each with the captures
    of those cameras only. A set missing a capture of one of its ``multicam_cameras`` (a
    store cut short) is never listed.
    """
    for camera in cameras or []:
        check_camera(session, camera)
    found: dict[str, dict[str, CaptureRecord]] = {}
    for frame in session.rig.sensors("camera"):
        for capture in session.captures(frame.name):
            name = capture.meta.get("multicam_set")
            if isinstance(name, str) and SET_NAME.fullmatch(name):
                found.setdefault(name, {})[frame.name] = capture
    sets = []
    for name in sorted(found, key=lambda n: int(n[3:])):
        records = found[name]
        members = [str(c) for c in next(iter(records.values())).meta.get("multicam_cameras", [])]
        if sorted(members) != sorted(records) or any(r.meta.get("multicam_cameras") != members
                                                     for r in records.values()):
            continue  # cut short, or inconsistent
        chosen = [c for c in members if cameras is None or c in cameras]
        if len(chosen) >= 2:
            sets.append(MulticamSet(name, {c: records[c] for c in chosen}))
    return sets


# --------------------------------------------------------------------------------------------
# Live capture


def _read_together(cameras: Sequence[str], read: Mapping[str, Callable[[], Sample]]) -> dict[str, Sample]:
    """One sample per camera, every read started at the same moment (a thread each, released together)."""
    start = threading.Barrier(len(cameras))

    def read_when_all_ready(camera: str) -> Sample:
        start.wait()
        return read[camera]()

    with ThreadPoolExecutor(max_workers=len(cameras), thread_name_prefix="multicam-read") as pool:
        futures = {camera: pool.submit(read_when_all_ready, camera) for camera in cameras}
        return {camera: future.result() for camera, future in futures.items()}


def _read_in_step(session: Session, cameras: Sequence[str], read: Mapping[str, Callable[[], Sample]],
                  tolerance_s: float) -> dict[str, Sample]:
    """:func:`_read_together` until the frame times (on the rig's clock) lie within ``tolerance_s`` (s), at most
    :data:`READ_ATTEMPTS` times (free-running cameras drift in and out of step); the last attempt's refusal names
    the late camera."""
    for attempt in range(1, READ_ATTEMPTS + 1):
        samples = _read_together(cameras, read)
        stamps = {camera: session.rig.get(camera).rig_time(sample.timestamp_s) for camera, sample in samples.items()}
        if attempt == READ_ATTEMPTS or max(stamps.values()) - min(stamps.values()) <= tolerance_s:
            _check_spread(stamps, tolerance_s)
            return samples


def capture_set(session: Session, cameras: list[str], read: Mapping[str, Callable[[], Sample]], *,
                tolerance_s: float = DEFAULT_TOLERANCE_S, require_board: bool = False, device: str,
                progress: ProgressCallback = no_progress) -> MulticamSet:
    """Read one frame from each camera at the same moment and store them as one set.

    ``read``: camera -> a function returning its next :class:`Sample` (all called at
    once, each in its own thread). Refused with :class:`InputError`, storing nothing,
    when the frame times spread over more than ``tolerance_s`` (s; the message says
    which camera was how late), an image's size differs from its camera's intrinsics or
    earlier captures, or (with ``require_board``) fewer than two cameras see the board.
    A camera that does not see the board is stored with no detection.
    """
    _check_cameras(session, cameras)
    _check_tolerance(tolerance_s)
    missing = [camera for camera in cameras if camera not in read]
    if missing:
        raise InputError(f"no way to read {', '.join(missing)}", missing[0])
    board = _set_board(session, require_board)
    progress(0.0, f"reading {', '.join(cameras)}")
    samples = _read_in_step(session, cameras, read, tolerance_s)
    for camera, sample in samples.items():
        _check_image(session, camera, sample.image)
    progress(0.3, "detecting the board")
    detections = _detect_all({camera: sample.image for camera, sample in samples.items()}, board)
    if require_board and not _enough_views(detections):
        raise InputError(f"the board {board} was found by {_views_text(detections)}; a set needs it in view of at "
                         f"least {MIN_BOARD_VIEWS}. No set was stored",
                         next(c for c, d in detections.items() if d is None))
    progress(0.9, "storing the set")
    return _store_set(session, samples, detections, device=device)


@contextlib.contextmanager
def _device_errors(camera: str) -> Iterator[None]:
    """A device that cannot be opened or read becomes an :class:`InputError` naming the camera."""
    try:
        yield
    except DeviceError as exc:
        raise InputError(f"{camera}: {exc.device}: {exc.message}; no set was stored", camera) from None


def _guarded_read(camera: str, device: CaptureDevice) -> Callable[[], Sample]:
    def read() -> Sample:
        with _device_errors(camera):
            return device.read()
    return read


def check_capture_devices(session: Session, cameras: list[str]) -> None:
    """Refuse ``cameras`` unless each is a camera of the rig with a capture device set (before any is opened)."""
    _check_cameras(session, cameras)
    for camera in cameras:
        if not session.rig.get(camera).device:
            raise InputError("no capture device configured for this camera; set one in the sensors step", camera)


def capture_set_from_devices(session: Session, cameras: list[str], *, tolerance_s: float = DEFAULT_TOLERANCE_S,
                             require_board: bool = False, progress: ProgressCallback = no_progress) -> MulticamSet:
    """:func:`capture_set` from each camera's device as set in the rig (opened for this capture)."""
    check_capture_devices(session, cameras)
    with contextlib.ExitStack() as stack:
        devices = {}
        for camera in cameras:
            with _device_errors(camera):
                devices[camera] = stack.enter_context(create_device(session.rig.get(camera).device))
        return capture_set(session, cameras, {camera: _guarded_read(camera, d) for camera, d in devices.items()},
                           tolerance_s=tolerance_s, require_board=require_board,
                           device=" + ".join(d.describe() for d in devices.values()), progress=progress)


# --------------------------------------------------------------------------------------------
# Importing a bag


@dataclass
class _TopicScan:
    """Frame times of one camera topic (first pass over the bag)."""

    stamps: list[float] = field(default_factory=list)
    """Frame time (s) of each converted frame: header stamp, or receive time when the stamp is zero."""
    positions: list[int] = field(default_factory=list)
    """Position of each converted frame on the topic (``meta["index"]``)."""


def _bag_error(camera: str, topic: str, exc: InputError) -> InputError:
    return InputError(f"{camera} ({topic}): {exc.message}; nothing was stored", exc.input)


def _open_topic(bag: Path, camera: str, topic: str, start_s: float | None, end_s: float | None) -> RosbagSource:
    """An opened replay of one image topic; :class:`InputError` naming the bag and the topic otherwise."""
    source = RosbagSource(str(bag), topic, start_s, end_s)
    try:
        source.open()
    except RosbagError as exc:
        raise _bag_error(camera, topic, exc) from None
    if source.msgtype not in (IMAGE, COMPRESSED_IMAGE):
        source.close()
        raise InputError(f"{camera}: topic {topic!r} in bag {bag} holds {source.msgtype}, not images; pick a "
                         f"{IMAGE} or {COMPRESSED_IMAGE} topic. Nothing was stored", str(bag))
    return source


def _next_frame(source: RosbagSource, camera: str, skipped: list[dict[str, Any]] | None) -> Sample | None:
    """The topic's next converted frame (None at its end); an unconvertible message is noted in ``skipped``."""
    while True:
        try:
            return source.read()
        except DeviceDisconnected:
            return None
        except RosbagError as exc:  # damaged part-way
            raise _bag_error(camera, source.topic, exc) from None
        except InputError as exc:  # one message that is no usable image
            if skipped is not None:
                skipped.append(exc.to_dict())


def _scan_topic(session: Session, source: RosbagSource, camera: str, report: CameraImport,
                tick: Callable[[], None]) -> _TopicScan:
    """Read every frame's time, checking that all frames share one size that suits the camera."""
    scan, first = _TopicScan(), None
    while (sample := _next_frame(source, camera, report.skipped)) is not None:
        tick()
        if first is None:
            first = sample
            _check_image(session, camera, sample.image)
        elif sample.image.shape[:2] != first.image.shape[:2]:
            raise InputError(f"{camera}: {source.topic} #{sample.meta['index']} in bag {source.path} is "
                             f"{sample.image.shape[1]}x{sample.image.shape[0]} px but #{first.meta['index']} is "
                             f"{first.image.shape[1]}x{first.image.shape[0]} px; all images of one camera must share "
                             "one size. Nothing was stored", str(source.path))
        scan.stamps.append(sample.timestamp_s)
        scan.positions.append(int(sample.meta["index"]))
    report.read = len(scan.stamps)
    return scan


class _FrameFetcher:
    """The frames of one topic by position, reading the replay forward once (second pass over the bag)."""

    def __init__(self, source: RosbagSource, camera: str, wanted: set[int]):
        self.source, self.camera, self.wanted = source, camera, wanted
        self._kept: dict[int, Sample] = {}

    def get(self, position: int) -> Sample:
        while position not in self._kept:
            sample = _next_frame(self.source, self.camera, None)
            if sample is None:
                raise InputError(f"{self.camera}: {self.source.topic} #{position} vanished from bag "
                                 f"{self.source.path} during the import", str(self.source.path))
            if sample.meta["index"] in self.wanted:
                self._kept[int(sample.meta["index"])] = sample
        return self._kept.pop(position)


def _check_import_settings(every: int, limit: int | None, tolerance_s: float) -> None:
    if every < 1 or (limit is not None and limit < 1):
        raise InputError(f"every and limit must be at least 1, not {every} and {limit}", "every")
    _check_tolerance(tolerance_s)


class _BagImport:
    """One import: the bag's camera topics read twice, first for the frame times, then for the chosen sets."""

    def __init__(self, session: Session, bag: Path, topics: Mapping[str, str],
                 window: tuple[float | None, float | None], check: ProgressCallback, report: BagImportReport):
        self.session, self.bag, self.topics, self.window, self.check, self.report = (
            session, bag, dict(topics), window, check, report)

    @contextlib.contextmanager
    def _sources(self) -> Iterator[dict[str, RosbagSource]]:
        with contextlib.ExitStack() as stack:
            sources = {}
            for camera, topic in self.topics.items():
                sources[camera] = _open_topic(self.bag, camera, topic, *self.window)
                stack.callback(sources[camera].close)
            yield sources

    def scan(self) -> dict[str, _TopicScan]:
        """First pass: every frame's time and place, all checked; nothing is stored."""
        with self._sources() as sources:
            total, done = max(sum(source.message_count or 0 for source in sources.values()), 1), 0

            def tick() -> None:
                nonlocal done
                done += 1
                self.check(SCAN_SHARE * min(done / total, 1.0), f"reading frame times: {done} frames")

            return {camera: _scan_topic(self.session, source, camera, self.report.cameras[camera], tick)
                    for camera, source in sources.items()}

    def store(self, chosen: list[dict[str, int]], board: BoardSpec | None, require_board: bool,
              limit: int | None) -> None:
        """Second pass: fetch, detect and store the chosen sets (camera -> position on its topic), in order."""
        report = self.report
        report.ended = f"end of bag after {report.matched_sets} matched sets"
        with self._sources() as sources:
            fetchers = {camera: _FrameFetcher(source, camera, {s[camera] for s in chosen if camera in s})
                        for camera, source in sources.items()}
            for k, positions in enumerate(chosen):
                if limit is not None and len(report.sets) >= limit:
                    report.ended = f"stopped at the limit of {limit} sets"
                    break
                self.check(SCAN_SHARE + (1 - SCAN_SHARE) * k / len(chosen),
                           f"{len(report.sets)} sets imported; detecting the board in set {k + 1} of {len(chosen)}")
                samples = {camera: fetchers[camera].get(position) for camera, position in positions.items()}
                detections = _detect_all({camera: sample.image for camera, sample in samples.items()}, board)
                if require_board and not _enough_views(detections):
                    report.no_board += 1
                    continue
                stored = _store_set(self.session, samples, detections, device=f"rosbag {self.bag}",
                                    sources={c: f"{self.topics[c]} #{p}" for c, p in positions.items()})
                report.sets.append(stored.name)
                for camera in stored.captures:
                    report.cameras[camera].stored += 1


def import_bag_sets(session: Session, bag_path: str | Path, topics: Mapping[str, str], *,
                    tolerance_s: float = DEFAULT_TOLERANCE_S, every: int = 1, limit: int | None = None,
                    start_s: float | None = None, end_s: float | None = None, require_board: bool = True,
                    progress: ProgressCallback = no_progress,
                    cancelled: Callable[[], bool] | None = None) -> BagImportReport:
    """Store the synchronised sets of a ROS 2 bag's image topics.

    ``topics``: camera -> its ``sensor_msgs/Image`` or ``CompressedImage`` topic. The
    frames (within ``start_s`` .. ``end_s``, seconds after the bag start, as the
    ``rosbag`` driver reads them) are matched by header stamp (the receive time when a
    stamp is zero) with :func:`match_by_timestamp`; every ``every``-th matched set is
    kept, up to ``limit`` sets, each with its board detections. With ``require_board``
    a set that fewer than two cameras see the board in is counted in ``no_board`` and
    not stored.

    The whole bag is read once before anything is stored, so a bad bag (missing, corrupt,
    a topic it lacks or that holds no images, images of the wrong size) raises
    :class:`InputError` naming the bag and the topic and stores nothing. Cancelling,
    through ``progress`` (a job's report raises :class:`CancelledError`) or
    ``cancelled()`` returning True, lands between sets and keeps the sets stored so far.
    """
    bag, cameras = Path(bag_path), list(topics)
    _check_cameras(session, cameras)
    _check_import_settings(every, limit, tolerance_s)
    if len(set(topics.values())) != len(cameras):
        raise InputError(f"each camera needs its own topic, not {dict(topics)}", "topics")
    board = _set_board(session, require_board)
    report = BagImportReport(str(bag), {camera: CameraImport(topic) for camera, topic in topics.items()})

    def check(fraction: float, message: str) -> None:
        if cancelled is not None and cancelled():
            raise CancelledError(f"import of {bag} cancelled after {len(report.sets)} sets; those are kept")
        progress(fraction, message)

    job = _BagImport(session, bag, topics, (start_s, end_s), check, report)
    scans = job.scan()
    report.clock_offsets_s = {camera: session.rig.get(camera).clock_offset_s for camera in cameras}
    match = match_by_timestamp({camera: np.asarray(scan.stamps) - report.clock_offsets_s[camera]
                                for camera, scan in scans.items()}, tolerance_s)
    report.matched_sets = len(match.sets)
    for camera, scan in scans.items():
        report.cameras[camera].unmatched = [scan.positions[i] for i in match.unmatched[camera]]
        report.cameras[camera].matched = report.cameras[camera].read - len(match.unmatched[camera])
    job.store([{camera: scans[camera].positions[i] for camera, i in s.items()} for s in match.sets[::every]],
              board, require_board, limit)
    progress(1.0, f"{len(report.sets)} sets imported; {report.ended}")
    return report
