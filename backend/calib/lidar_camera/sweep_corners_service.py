"""Board corners in a swept scanner's intensity image, and a camera on a pan head (the servo-scanner rig), for a
session or for files; shared by the API, the studio and the CLI.

A shot is one placement of the board seen by both sensors: a whole sweep of the swept scanner (its raw scans,
:mod:`backend.calib.sweep.service`), the camera's image, and the pan head's reading when the image was taken (deg;
0 for a camera that does not pan). In a session a shot is a stored image + sweep pair
(:mod:`backend.calib.lidar_camera.capture`), the reading kept as the image's ``meta["pan_rad"]``
(:data:`PAN_META_KEY`); every sweep is re-assembled with the scanner's current geometry (its device's, what step 5
accepted). In files a sweep is what the session store keeps for a swept capture (:func:`read_sweep_file`). Each
sweep's board corners are found in its intensity image and lifted to 3D
(:func:`~backend.calib.lidar_camera.sweep_corners.find_sweep_corners`), and paired with the camera's (found when the
pair was stored, or found now).

- :func:`solve_corners`: ``T_camera_lidar`` by the corners method from the shots at one pan reading, cross-checked by
  the target method on the same sweeps. :func:`solve_corners_session` keeps it as a ``lidar_camera`` result of
  method ``corners`` with its before/after overlays, like every LiDAR-camera result (the rig accepts it as the
  camera's edge).
- :func:`solve_pan`: the camera's pose at pan reading 0 and its pan axis from shots at two or more readings
  (:func:`~backend.calib.lidar_camera.pan_axis.solve_pan_axis`), each position's own solve the cross-check.
  :func:`solve_pan_session` keeps it as a ``lidar_camera`` result of method ``pan_axis`` (the axis in its
  diagnostics).

A shot whose board is not found in the sweep (too small or too far: its squares span too few servo steps) or in the
image is left out and named in the result's warnings; a solve left with none is refused naming them.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from backend.calib._session import check_camera, session_plane_board
from backend.calib.board.detection import Detection, detect_board
from backend.calib.lidar_camera.capture import CapturePair, stored_pairs
from backend.calib.lidar_camera.pan_axis import (
    PanAxisResult,
    PanPosition,
    camera_at_reading,
    guess_at_reading,
    solve_pan_axis,
)
from backend.calib.lidar_camera.service import KIND, PairData, camera_intrinsics, lidar_camera_record, overlay_files
from backend.calib.lidar_camera.sweep_corners import (
    CornerPlacement,
    SweepCorners,
    find_sweep_corners,
    solve_sweep_corners,
)
from backend.calib.sweep import service as sweep_service
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics, check_image_size
from backend.core.errors import InputError
from backend.core.projection import colourise_cloud
from backend.core.result import ProgressCallback, StoredResult, TransformResult, no_progress
from backend.core.sweep_geometry import SWEEP_META_KEYS, ScanAtAngle, SweepGeometry, scans_from_capture
from backend.devices.cloud_files import read_cloud
from backend.devices.image_io import read_image
from backend.plots.sweep_corners import sweep_corners_view
from backend.store.schema import CaptureRecord
from backend.store.session import Session

PAN_META_KEY = "pan_rad"
"""The key of an image capture's meta holding the pan head's reading when it was taken (rad)."""
PAN_DECIMALS_DEG = 1
"""Readings equal to this many decimals of a degree are one pan position."""
METHODS = ("corners", "pan_axis")
"""The LiDAR-camera methods solved here."""
CORNERS_METHOD = "the corners method"


@dataclass
class SweepShot:
    """One placement of the board: the sweep and the camera's image of it, at one reading of the pan head."""

    name: str
    """How results and errors name it (a stored pair's name, or ``sweep.npy:image.png``)."""
    scans: list[ScanAtAngle]
    """The raw sweep: per servo step, its reading (rad), points (m, scanner frame), intensities."""
    image: np.ndarray
    """The camera's uint8 image."""
    pan_deg: float = 0.0
    """The pan head's reading (deg, rounded to :data:`PAN_DECIMALS_DEG`)."""
    detection: Detection | None = None
    """The board's corners found in the image when it was stored, or None: found now."""


@dataclass
class Placements:
    """The placements a solve can use, their sweeps assembled (mount frame, m), and the shots left out (why)."""

    found: list[CornerPlacement]
    clouds: list[np.ndarray]
    shots: list[SweepShot]
    skipped: list[str]


def _placements(shots: Sequence[SweepShot], board: BoardSpec, camera: CameraIntrinsics, geometry: SweepGeometry,
                progress: ProgressCallback) -> Placements:
    """Each shot's corners in its sweep (assembled with ``geometry``) and in its image; a shot whose board is not
    found in either is left out, named with the reason. :class:`InputError` when none is left."""
    kept = Placements([], [], [], [])
    for i, shot in enumerate(shots):
        progress(i / len(shots), f"finding the board's corners in {shot.name}")
        check_image_size(shot.image, camera, shot.name)
        try:
            corners = find_sweep_corners(shot.scans, geometry, board, shot.name)
            detection = shot.detection or detect_board(shot.image, board)
            if detection is None:
                raise InputError(f"{shot.name}: the board is not found in the camera's image", shot.name)
        except InputError as error:
            kept.skipped.append(error.message)
            continue
        kept.found.append(CornerPlacement(shot.name, corners, detection))
        kept.clouds.append(geometry.assemble(shot.scans)[0])
        kept.shots.append(shot)
    if not kept.found:
        raise InputError("the board is not found in any shot: " + "; ".join(kept.skipped[:3]),
                         shots[0].name if shots else "pairs")
    return kept


def solve_corners(shots: Sequence[SweepShot], board: BoardSpec, camera: CameraIntrinsics, geometry: SweepGeometry,
                  T_init: np.ndarray, *, camera_frame: str = "camera", lidar_frame: str = "lidar",
                  progress: ProgressCallback = no_progress) -> tuple[TransformResult, Placements]:
    """``T_camera_lidar`` by the corners method from ``shots`` taken at one pan reading, judged, and the placements
    it used (their shots and assembled sweeps). ``T_init`` (4x4, m), the mounting guess at reading 0, turned to
    that reading, chooses how a half-turn-symmetric board's corners pair. The result's diagnostics hold
    ``pan_deg``; away from reading 0 it is the camera turned there, which its warnings say."""
    readings = {shot.pan_deg for shot in shots}
    if len(readings) > 1:
        listed = ", ".join(f"{reading:+g}" for reading in sorted(readings))
        raise InputError(f"the shots were taken at {len(readings)} pan readings ({listed} deg): the corners method "
                         "solves one camera position; solve the pan axis for several", "pan")
    pan_deg = readings.pop() if readings else 0.0
    kept = _placements(shots, board, camera, geometry, lambda f, m: progress(0.7 * f, m))
    progress(0.7, f"solving from {len(kept.found)} placements")
    result = solve_sweep_corners(kept.found, board, camera, camera_frame, lidar_frame,
                                 guess_at_reading(T_init, math.radians(pan_deg)), kept.clouds)
    result.warnings[:0] = kept.skipped
    result.diagnostics["pan_deg"] = pan_deg
    if pan_deg != 0.0:
        result.warnings.append(f"the camera turned to pan {pan_deg:+g} deg: accepting this puts {camera_frame} where "
                               "it was then; the pan axis places it at reading 0")
    return result, kept


def solve_pan(shots: Sequence[SweepShot], board: BoardSpec, camera: CameraIntrinsics, geometry: SweepGeometry,
              T_init: np.ndarray, *, progress: ProgressCallback = no_progress
              ) -> tuple[PanAxisResult, list[SweepShot], list[str]]:
    """The camera's pan-axis model from ``shots`` at two or more pan readings, the shots it used and the ones left
    out (why). ``T_init`` (4x4, m): the mounting guess at reading 0, which pairs a half-turn-symmetric board's
    corners."""
    readings = sorted({shot.pan_deg for shot in shots})
    if len(readings) < 2:
        raise InputError(f"every shot was taken at pan {readings[0] if readings else 0:+g} deg: the pan axis needs "
                         "shots at two or more readings", "pan")
    positions, used, skipped = [], [], []
    for k, reading in enumerate(readings):
        kept = _placements([shot for shot in shots if shot.pan_deg == reading], board, camera, geometry,
                           lambda f, m, k=k: progress(0.7 * (k + f) / len(readings), m))
        positions.append(PanPosition(math.radians(reading), kept.found))
        used += kept.shots
        skipped += kept.skipped
    progress(0.7, f"solving the pan axis from {len(positions)} positions")
    return solve_pan_axis(positions, board, camera, T_init), used, skipped


# -------------------------------------------------------------------------------------------- a session's shots


def pan_reading_deg(image: CaptureRecord) -> float:
    """The pan head's reading (deg, rounded to :data:`PAN_DECIMALS_DEG`) an image capture was taken at: its
    ``meta[PAN_META_KEY]``, 0 without one."""
    return round(math.degrees(float(image.meta.get(PAN_META_KEY, 0.0))), PAN_DECIMALS_DEG)


def sweep_pairs(session: Session, camera: str, lidar: str, *, pan_deg: float | None = None,
                image_ids: list[str] | None = None) -> list[CapturePair]:
    """The stored pairs of ``camera`` and the swept scanner ``lidar`` whose cloud is a whole sweep, oldest first:
    those at the pan reading ``pan_deg`` (deg) when given, those of ``image_ids`` when given. :class:`InputError`
    naming the sensor when ``lidar`` is not a swept scanner."""
    check_camera(session, camera)
    sweep_service.check_swept(session, lidar)
    return [pair for pair in stored_pairs(session, camera, lidar, image_ids)
            if all(key in pair.cloud.meta for key in SWEEP_META_KEYS)
            and (pan_deg is None or pan_reading_deg(pair.image) == round(pan_deg, PAN_DECIMALS_DEG))]


def pan_readings(session: Session, camera: str, lidar: str) -> dict[float, int]:
    """The pan readings (deg, rising) of the stored image + sweep pairs of ``camera`` and ``lidar``, and how many
    pairs each holds."""
    readings = [pan_reading_deg(pair.image) for pair in sweep_pairs(session, camera, lidar)]
    return {reading: readings.count(reading) for reading in sorted(set(readings))}


def session_shots(session: Session, camera: str, lidar: str, pairs: Sequence[CapturePair]) -> list[SweepShot]:
    """The stored ``pairs`` as shots: each sweep's raw scans, its image and the image's pan reading."""
    return [SweepShot(pair.name, sweep_service.capture_scans(session, lidar, pair.cloud),
                      session.capture_image(camera, pair.image.id), pan_reading_deg(pair.image),
                      Detection.from_dict(pair.image.detection) if pair.image.detection else None)
            for pair in pairs]


def corners_inputs(session: Session, camera: str, lidar: str, pan_deg: float = 0.0,
                   image_ids: list[str] | None = None) -> tuple[CameraIntrinsics, BoardSpec, list[CapturePair]]:
    """What :func:`solve_corners_session` solves from, checked before any work: the camera's intrinsics, the
    session's board and the pairs at pan reading ``pan_deg`` (deg; those of ``image_ids`` when given).
    :class:`InputError` naming what is missing."""
    intrinsics = camera_intrinsics(session, camera)
    board = session_plane_board(session, CORNERS_METHOD)
    pairs = sweep_pairs(session, camera, lidar, pan_deg=pan_deg, image_ids=image_ids)
    if not pairs:
        raise InputError(f"no image + sweep pairs of {camera} and {lidar} at pan {pan_deg:+g} deg; the pairs' "
                         f"readings: {_readings_text(session, camera, lidar)}", "pan_deg")
    return intrinsics, board, pairs


def pan_inputs(session: Session, camera: str, lidar: str) -> tuple[CameraIntrinsics, BoardSpec, list[CapturePair]]:
    """What :func:`solve_pan_session` solves from, checked before any work: the camera's intrinsics, the session's
    board and the pairs, at two or more pan readings. :class:`InputError` naming what is missing."""
    intrinsics = camera_intrinsics(session, camera)
    board = session_plane_board(session, CORNERS_METHOD)
    pairs = sweep_pairs(session, camera, lidar)
    if len({pan_reading_deg(pair.image) for pair in pairs}) < 2:
        raise InputError(f"the pan axis needs image + sweep pairs of {camera} and {lidar} at two or more pan readings; "
                         f"their readings: {_readings_text(session, camera, lidar)}", "pairs")
    return intrinsics, board, pairs


def solve_corners_session(session: Session, camera: str, lidar: str, *, pan_deg: float = 0.0,
                          image_ids: list[str] | None = None, T_init: np.ndarray | None = None,
                          progress: ProgressCallback = no_progress) -> tuple[str, TransformResult]:
    """Solve ``T_camera_lidar`` by the corners method from the stored pairs at pan reading ``pan_deg`` (deg; only
    those of ``image_ids`` when given) and keep the result (not yet accepted) with its before/after overlays.
    ``T_init``: the mounting guess at reading 0 (4x4, m; default the rig's current transform)."""
    intrinsics, board, pairs = corners_inputs(session, camera, lidar, pan_deg, image_ids)
    shots = session_shots(session, camera, lidar, pairs)
    geometry = sweep_service.rig_geometry(session.rig, lidar)
    T_init = session.rig.T_a_b(camera, lidar) if T_init is None else np.asarray(T_init, dtype=float)
    result, used = solve_corners(shots, board, intrinsics, geometry, T_init, camera_frame=camera, lidar_frame=lidar,
                                 progress=lambda f, m: progress(0.9 * f, m))
    progress(0.9, "drawing the before/after overlays")
    scenes = [PairData(shot.name, shot.name, shot.image, cloud, None)
              for shot, cloud in zip(used.shots, used.clouds, strict=True)]
    files = overlay_files(scenes, intrinsics, guess_at_reading(T_init, math.radians(pan_deg)), result.T_parent_child)
    return session.add_result(lidar, result.to_record(), inputs=[shot.name for shot in used.shots],
                              files=files), result


def solve_pan_session(session: Session, camera: str, lidar: str, *, T_init: np.ndarray | None = None,
                      progress: ProgressCallback = no_progress) -> tuple[str, TransformResult]:
    """The camera's pose at pan reading 0 and its pan axis from the stored pairs at every reading (two or more),
    kept as a ``lidar_camera`` result of method ``pan_axis`` (not yet accepted). ``T_init``: the mounting guess at
    reading 0 (4x4, m; default the rig's current transform)."""
    intrinsics, board, pairs = pan_inputs(session, camera, lidar)
    shots = session_shots(session, camera, lidar, pairs)
    T_init = session.rig.T_a_b(camera, lidar) if T_init is None else np.asarray(T_init, dtype=float)
    pan, used, skipped = solve_pan(shots, board, intrinsics, sweep_service.rig_geometry(session.rig, lidar), T_init,
                                   progress=progress)
    result = pan.transform(camera, lidar)
    result.warnings[:0] = skipped
    return session.add_result(lidar, result.to_record(), inputs=[shot.name for shot in used]), result


def _readings_text(session: Session, camera: str, lidar: str) -> str:
    """The pairs' pan readings as a person reads them: ``+45 deg (4 pairs), 0 deg (6 pairs)``, or ``none``."""
    readings = pan_readings(session, camera, lidar)
    return ", ".join(f"{reading:+g} deg ({count} pairs)" for reading, count in readings.items()) or "no pairs"


# -------------------------------------------------------------------------------------------- looking at results


def sweep_corners(session: Session, lidar: str, capture_id: str) -> SweepCorners:
    """The session board's corners in the stored sweep ``capture_id`` of the swept scanner ``lidar``, assembled with
    its current geometry; :class:`InputError` naming ``<lidar>:<capture_id>`` when the board is not found or too
    small there."""
    board = session_plane_board(session, CORNERS_METHOD)
    scans = sweep_service.capture_scans(session, lidar, sweep_service.swept_capture(session, lidar, capture_id))
    return find_sweep_corners(scans, sweep_service.rig_geometry(session.rig, lidar), board, f"{lidar}:{capture_id}")


def sweep_corners_image(session: Session, lidar: str, capture_id: str) -> np.ndarray:
    """RGB view of :func:`sweep_corners`: the intensity image around the board with its corners marked."""
    board = session_plane_board(session, CORNERS_METHOD)
    return sweep_corners_view(sweep_corners(session, lidar, capture_id), board.cols)


def corners_results(session: Session, camera: str, lidar: str) -> list[dict[str, Any]]:
    """The stored LiDAR-camera results of ``camera`` and ``lidar`` by the corners and pan-axis methods, oldest
    first."""
    return [record for record in session.results(lidar, KIND)
            if record.get("method") in METHODS and StoredResult(record).edges[0].parent == camera]


def camera_at_pan(record: dict[str, Any], pan_deg: float) -> np.ndarray:
    """``T_camera_lidar`` (4x4, m) a stored LiDAR-camera result puts the camera at, at pan reading ``pan_deg``
    (deg): a pan-axis result turns its pose at reading 0 about its axis; any other holds one transform."""
    transform = StoredResult(record).edges[0]
    axis = transform.diagnostics.get("pan_axis") if transform.method == "pan_axis" else None
    if axis is None:
        return transform.T_parent_child
    return camera_at_reading(transform.T_parent_child, np.array(axis["axis"]), np.array(axis["axis_point_m"]),
                             math.radians(pan_deg))


@dataclass
class ColouredSweep:
    """A stored sweep coloured by the image taken with it, through a result's ``T_camera_lidar``."""

    points_m: np.ndarray
    """(M, 3) the sweep's points the camera sees (the scanner's mount frame, m)."""
    colours: np.ndarray
    """(M, 3) uint8 RGB: each point's pixel."""
    total: int
    """Points in the sweep."""


def coloured_sweep(session: Session, lidar: str, result_id: str, image_id: str) -> ColouredSweep:
    """The sweep paired with the image capture ``image_id`` coloured by that image through the result ``result_id``
    (at the image's pan reading, :func:`camera_at_pan`), assembled with the scanner's current geometry; the points
    the camera does not see are left out."""
    record = lidar_camera_record(session, lidar, result_id)
    camera = StoredResult(record).edges[0].parent
    pairs = sweep_pairs(session, camera, lidar, image_ids=[image_id])
    if not pairs:
        raise InputError(f"image {image_id} of {camera} is paired with no sweep of {lidar}", "image")
    geometry = sweep_service.rig_geometry(session.rig, lidar)
    points = geometry.assemble(sweep_service.capture_scans(session, lidar, pairs[0].cloud))[0]
    colours, seen = colourise_cloud(points, camera_at_pan(record, pan_reading_deg(pairs[0].image)),
                                    camera_intrinsics(session, camera), session.capture_image(camera, image_id))
    return ColouredSweep(points[seen], colours[seen], len(points))


# -------------------------------------------------------------------------------------------- files


def read_sweep_file(path: Path, geometry: SweepGeometry | None = None) -> tuple[list[ScanAtAngle], SweepGeometry]:
    """A sweep kept as the session store keeps a swept capture: ``path`` a point cloud (``.npy`` N x 4: x, y, z in
    the sweep's mount frame (m) and intensity, in scan order; any cloud file :func:`read_cloud` reads) and beside it
    ``<stem>.json``, the capture's record (or its ``meta`` alone) holding ``servo_angles_rad``, ``step_counts`` and
    ``geometry`` (the :class:`SweepGeometry` the points were assembled with). Returns the raw scans and the geometry
    to assemble them with: ``geometry`` when given, else the file's. :class:`InputError` naming the file."""
    path = Path(path)
    sidecar = path.with_suffix(".json")
    try:
        record = json.loads(sidecar.read_text())
    except OSError as exc:
        raise InputError(f"cannot read the sweep's record ({exc.strerror}): a sweep file comes with a JSON beside it "
                         "holding servo_angles_rad, step_counts and geometry", str(sidecar)) from None
    except json.JSONDecodeError as exc:
        raise InputError(f"not JSON ({exc.msg} at line {exc.lineno})", str(sidecar)) from None
    meta = record.get("meta", record) if isinstance(record, dict) else None
    if not isinstance(meta, dict):
        raise InputError("expected a JSON object holding servo_angles_rad, step_counts and geometry", str(sidecar))
    cloud = read_cloud(path)
    try:
        scans = scans_from_capture(cloud.points, cloud.intensity, meta)
        return scans, geometry or SweepGeometry.from_dict(meta["geometry"])
    except (ValueError, TypeError) as exc:
        raise InputError(f"{path.name}: {exc}", str(sidecar)) from None


def file_shots(sweeps: Sequence[tuple[Path, Path]], pan_deg: Sequence[float] | None,
               geometry: SweepGeometry | None = None) -> tuple[list[SweepShot], SweepGeometry]:
    """Shots from ``(sweep file, image file)`` pairs (:func:`read_sweep_file`, :func:`read_image`), taken at the pan
    readings ``pan_deg`` (deg, one per pair; None: all at 0), and the geometry to assemble every sweep with:
    ``geometry`` when given, else the first sweep's (all must agree)."""
    if pan_deg is not None and len(pan_deg) != len(sweeps):
        raise InputError(f"{len(pan_deg)} pan reading(s) for {len(sweeps)} sweep(s): give one --pan-deg per --sweep, "
                         "in the same order", "--pan-deg")
    shots, geometries = [], []
    for k, (sweep_path, image_path) in enumerate(sweeps):
        scans, found = read_sweep_file(sweep_path, geometry)
        geometries.append(found)
        shots.append(SweepShot(f"{Path(sweep_path).name}:{Path(image_path).name}", scans, read_image(image_path),
                               0.0 if pan_deg is None else round(float(pan_deg[k]), PAN_DECIMALS_DEG)))
    if any(g.to_dict() != geometries[0].to_dict() for g in geometries):
        raise InputError("the sweeps were assembled with different geometries: give the one to use with --geometry",
                         "--geometry")
    return shots, geometries[0]
