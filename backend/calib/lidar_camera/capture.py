"""Image + cloud pairs for LiDAR-to-camera calibration: captured together, stored linked, listed.

A pair is one moment seen by both sensors: the camera's image and the LiDAR's cloud,
each stored as an ordinary capture of its sensor, the image carrying the link
(``meta["paired_cloud"] = "<lidar>:<capture id>"``) and the two sensors' clock offsets the pair assumed
(``meta["clock_offsets_s"]``, s: the rig's accepted time offsets, 0 until one is accepted). A pair is all or
nothing: both are checked (the image's size against the intrinsics and the camera's earlier captures, the
cloud's points) before either is written, under the session's lock.

Capturing from live devices waits for a still board: the camera is read before and
after the LiDAR scan, and the pair is kept only when the board's corners moved less
than ``still_px`` between the two frames (a board carried while the LiDAR spins would
put the two sensors' boards in different places). Images without a board are fine
for the targetless method; with ``require_board`` they are refused, naming the frame.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from backend.calib._session import check_camera, check_lidar, pair_board, read_uploaded_cloud, store_cloud
from backend.calib.board.detection import Detection, common_corners, detect_board
from backend.calib.board.live_detection import detect_board_live
from backend.calib.intrinsics import service as intrinsics_service
from backend.core.accumulation import check_integration_s
from backend.core.camera import check_image_size
from backend.core.errors import InputError, NotFoundError
from backend.core.result import ProgressCallback, no_progress
from backend.devices.accumulate import read_accumulated
from backend.devices.base import DeviceError, Sample, create_device
from backend.devices.image_io import decode_image_bytes
from backend.store.schema import CaptureRecord
from backend.store.session import Session

STILL_PX = 1.0
"""Largest corner motion (px) between the camera frames before and after the scan for the board to count as still."""
CAPTURE_ATTEMPTS = 10
"""Reads of a pair before giving up on a board that keeps moving."""


@dataclass(frozen=True)
class CapturePair:
    """One image and one cloud of the same moment (both stored captures)."""

    camera: str
    image: CaptureRecord
    lidar: str
    cloud: CaptureRecord

    @property
    def name(self) -> str:
        """How results and errors name the pair: ``cam_front:00003+lidar_top:00007``."""
        return f"{self.camera}:{self.image.id}+{self.lidar}:{self.cloud.id}"

    @property
    def clock_offsets_s(self) -> dict[str, float]:
        """The camera's and the LiDAR's clock offsets (s) when the pair was stored (empty for older pairs)."""
        return dict(self.image.meta.get("clock_offsets_s", {}))


def stored_pairs(session: Session, camera: str, lidar: str, image_ids: list[str] | None = None) -> list[CapturePair]:
    """The stored pairs of ``camera`` and ``lidar``, oldest first (only those whose image is in ``image_ids``)."""
    check_camera(session, camera)
    check_lidar(session, lidar)
    clouds = {c.id: c for c in session.captures(lidar)}
    found = []
    for image in session.captures(camera):
        sensor, _, cloud_id = image.meta.get("paired_cloud", "").partition(":")
        if sensor == lidar and cloud_id in clouds and (image_ids is None or image.id in image_ids):
            found.append(CapturePair(camera, image, lidar, clouds[cloud_id]))
    if image_ids is not None:
        missing = sorted(set(image_ids) - {p.image.id for p in found})
        if missing:
            raise NotFoundError(f"no {camera}+{lidar} pair with image capture(s) {', '.join(missing)}", "pairs")
    return found


def store_pair(session: Session, camera: str, lidar: str, image: Sample, cloud: Sample, *, device: str,
               detection: Detection | None, source: tuple[str, str] | None = None) -> CapturePair:
    """Keep one image sample and one cloud sample as a linked pair (``source``: their original file names)."""
    check_camera(session, camera)
    image_name = source[0] if source else camera
    with session.lock:  # checked and stored as one: no capture in between changes what was checked
        intrinsics = session.rig.get(camera).intrinsics
        if intrinsics is not None:
            check_image_size(image.image, intrinsics, image_name)
        intrinsics_service.check_size(session, camera, image_name, image.image)
        cloud_record = store_cloud(session, lidar, cloud, device=device, source=source[1] if source else None)
        image_record = intrinsics_service.store_capture(
            session, camera, image.image, detection, device=device, timestamp_s=image.timestamp_s,
            source=source[0] if source else None,
            meta={**image.storable_meta(), "paired_cloud": f"{lidar}:{cloud_record.id}",
                  "clock_offsets_s": {sensor: session.rig.get(sensor).clock_offset_s for sensor in (camera, lidar)}})
    return CapturePair(camera, image_record, lidar, cloud_record)


def import_pair(session: Session, camera: str, lidar: str, image_file: tuple[str, bytes],
                cloud_file: tuple[str, bytes]) -> CapturePair:
    """Add an uploaded image and cloud as a pair; an unreadable file or a wrong image size stores nothing."""
    check_camera(session, camera)
    check_lidar(session, lidar)
    image_name, cloud_name = Path(image_file[0]).name, Path(cloud_file[0]).name
    image = decode_image_bytes(image_file[1], image_name)
    cloud = read_uploaded_cloud(cloud_name, cloud_file[1])
    board = pair_board(session)
    detection = detect_board(image, board) if board else None
    return store_pair(session, camera, lidar, Sample(time.time(), image=image), cloud, device="upload",
                      detection=detection, source=(image_name, cloud_name))


def _corner_motion_px(before: Detection, after: Detection) -> float:
    """Largest motion (px) of a corner detected in both frames; inf when they share none.

    Two detectors may number a whole checkerboard from opposite ends (a half turn of the numbering), so for two
    whole grids the smaller motion of the two numberings counts: only a board given a half turn in the plane
    during the scan would look still that way.
    """
    then_px, now_px = common_corners(before, after)
    if not len(then_px):
        return float("inf")
    motion = np.max(np.linalg.norm(then_px - now_px, axis=1))
    if len(before.ids) == len(after.ids) == len(then_px):
        motion = min(motion, np.max(np.linalg.norm(then_px - now_px[::-1], axis=1)))
    return float(motion)


def capture_pair(session: Session, camera: str, lidar: str, read_image: Callable[[], Sample],
                 read_cloud: Callable[[], Sample], *, device: str, require_board: bool = True,
                 still_px: float = STILL_PX, attempts: int = CAPTURE_ATTEMPTS,
                 progress: ProgressCallback = no_progress) -> CapturePair:
    """Read a still moment from both sensors and store it as a pair.

    Reads a frame, a scan, and a frame again; with a board in view, the pair is kept once
    the board's corners moved less than ``still_px`` (px) between the two frames, after at
    most ``attempts`` tries. Raises :class:`InputError` when the board is not found (with
    ``require_board``) or never holds still; nothing is stored then.
    """
    check_camera(session, camera)
    check_lidar(session, lidar)
    board = pair_board(session)
    if require_board and board is None:
        raise InputError("the session has no calibration board set (a test field is not one: the pairs do not "
                         "show the wall); set one in the session step", "board")
    motion = float("inf")
    with ThreadPoolExecutor(max_workers=1) as pool:
        for attempt in range(attempts):
            progress(attempt / attempts, "reading the camera and the LiDAR" if attempt == 0
                     else f"the board moved {motion:.1f} px during the scan: hold it still (try {attempt + 1})")
            before = read_image()
            # The first frame's board (the one stored) is searched while the LiDAR scans and the second frame is
            # read and searched by the fast preview detector, which only has to say whether the board moved; the
            # accurate one looks again where that finds nothing (squares too small for it). A click waits for one
            # accurate detection, not two in a row.
            found_before = pool.submit(detect_board, before.image, board) if board is not None else None
            cloud, after = read_cloud(), read_image()
            detection_before = detection_after = None
            if found_before is not None:
                detection_after = detect_board_live(after.image, board)
                detection_before = found_before.result()
                if detection_after is None and detection_before is not None:
                    detection_after = detect_board(after.image, board)
            if detection_before is None or detection_after is None:
                if require_board:
                    raise InputError(f"the board {board} was not found in {camera}'s image; bring it into view of "
                                     f"both {camera} and {lidar}", camera)
                return store_pair(session, camera, lidar, before, cloud, device=device, detection=detection_before)
            motion = _corner_motion_px(detection_before, detection_after)
            if motion <= still_px:
                return store_pair(session, camera, lidar, before, cloud, device=device, detection=detection_before)
    raise InputError(f"the board kept moving ({motion:.1f} px between the frames before and after the scan, more "
                     f"than {still_px} px) in {attempts} tries; hold it still while the pair is captured", camera)


def capture_pair_from_devices(session: Session, camera: str, lidar: str, *, require_board: bool = True,
                              integration_s: float | None = None,
                              progress: ProgressCallback = no_progress) -> CapturePair:
    """:func:`capture_pair` from the two sensors' devices as set in the rig (opened for this capture). With
    ``integration_s`` (s) the cloud is the LiDAR's frames over that much of its time added up
    (:func:`~backend.devices.accumulate.read_accumulated`: a non-repetitive Livox fills its field of view), and the
    board must hold still for all of it; ``meta`` keeps ``integration_s`` and the ``coverage`` reached."""
    for sensor in (camera, lidar):
        if not session.rig.get(sensor).device:
            raise InputError("no capture device configured for this sensor; set one in the sensors step", sensor)
    if integration_s is not None:
        check_integration_s(integration_s)
    try:
        with create_device(session.rig.get(camera).device) as camera_device, \
                create_device(session.rig.get(lidar).device) as lidar_device:

            def read_cloud() -> Sample:
                if integration_s is None:
                    return lidar_device.read()
                started_s = time.time()
                cloud = read_accumulated(lidar_device, integration_s)
                return Sample(started_s, points=cloud.points, intensity=cloud.intensity, meta={
                    "integration_s": integration_s, "frames": cloud.frames, "coverage": cloud.coverage.share})

            return capture_pair(session, camera, lidar, camera_device.read, read_cloud,
                                device=f"{camera_device.describe()} + {lidar_device.describe()}",
                                require_board=require_board, progress=progress)
    except DeviceError as exc:  # unplugged or unreachable: nothing was stored; say which device and why
        raise InputError(f"{exc.device}: {exc.message}; no pair was stored", exc.device) from None
