"""Time offsets as the CLI, the API and the studio call them: the session's captures of two sensors watching one
moving board, lined up, kept as a result, and accepted as the second sensor's clock offset in the rig.

Pairs of sensors and the signal each gives (:mod:`.signals`):

- camera + 3D LiDAR: the board's normal (the camera's from PnP, the LiDAR's from the board plane placed by the
  rig's current ``T_camera_lidar``);
- camera + 2D scanner: the board's line in the scan plane (the scanner's segment, and where the camera's board plane
  cuts the scan plane through the rig's current camera-scanner transform, :mod:`.scan_line`); the board is turned
  about a vertical axis while carried across the scan plane;
- camera + camera: the cameras' angular rates relative to the board (its pose, frame to frame);
- 3D LiDAR + 3D LiDAR: each LiDAR's angular rates from its own odometry (scan-to-scan GICP,
  :func:`~backend.calib.lidar_imu.odometry.scan_poses`) while the rig turns in a static scene.

Every capture of each sensor with its time stamp enters (the camera's with a board detection); a recording is
captured live while the board is carried through both views, or imported. Accepting the result sets
``clock_offset_s`` of sensor b to a's plus the offset (``t_b = t_a + offset``), and the matching of pairs and sets
then works on the rig's time (:meth:`~backend.core.rig.Frame.rig_time`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from backend.calib._session import session_plane_board
from backend.calib.board.detection import Detection
from backend.calib.camera_imu.observations import (
    board_poses,
    check_board_points,
    detect_image_folder,
    read_detections_csv,
)
from backend.calib.lidar_imu.odometry import scan_poses
from backend.calib.lidar_imu.service import MAX_SCANS, read_scan_folder
from backend.calib.time_offset.board_signals import camera_board_poses, lidar_signal
from backend.calib.time_offset.scan_line import planar_scans, scan_line_signals
from backend.calib.time_offset.signals import MotionSignal, board_normal_signal, orientation_rate_signal
from backend.calib.time_offset.solver import KIND, TimeOffsetResult, TimeOffsetSettings, solve_time_offset
from backend.core.boards import BoardSpec
from backend.core.errors import InputError
from backend.core.result import ProgressCallback, no_progress
from backend.core.rig import Rig
from backend.exports.ros_camera_info import load_camera_info
from backend.store.schema import RECORDING_META_KEY, CaptureRecord
from backend.store.session import Session

SUPPORTED = ("camera + 3D LiDAR, camera + 2D scanner or camera + camera (a board carried through both views), or 3D "
             "LiDAR + 3D LiDAR (the rig turned in a static scene)")
PAIRS = (("camera", "lidar3d"), ("camera", "lidar2d"), ("camera", "camera"), ("lidar3d", "lidar3d"))


def settings(max_offset_s: float) -> TimeOffsetSettings:
    """The search's settings for offsets within ``±max_offset_s`` (s; 1 ms steps)."""
    return TimeOffsetSettings(max_offset_s=max_offset_s, step_s=min(1e-3, max_offset_s))


def slot(sensor: str) -> str:
    """The acceptance slot of a sensor's clock offset."""
    return f"{sensor}/clock_offset"


def apply_clock_offset(rig: Rig, record: dict[str, Any]) -> None:
    """Accepting a time-offset result: sensor b's clock offset becomes a's plus the offset, with its sigma."""
    reference, sensor = rig.get(record["sensor_a"]), rig.get(record["sensor_b"])
    sensor.clock_offset_s = reference.clock_offset_s + float(record["time_offset_s"])
    sensor.clock_offset_std_s = float(np.hypot(record["std"]["time_s"], reference.clock_offset_std_s or 0.0))


def transform_clock_record(record: dict[str, Any]) -> dict[str, Any]:
    """A stored camera-IMU or LiDAR-IMU result's time offset (``t_imu = t_parent + offset``, in its diagnostics) as
    a time-offset result gives it, for the accept that sets the IMU's clock offset."""
    diagnostics = record["diagnostics"]
    return {"sensor_a": record["parent"], "sensor_b": record["child"], "time_offset_s": diagnostics["time_offset_s"],
            "std": {"time_s": diagnostics["time_offset_std_s"]}}


def _captures(session: Session, sensor: str, recording: str | None) -> list[CaptureRecord]:
    """The sensor's captures, or only those of ``recording`` (their ``meta["recording"]``); :class:`InputError`
    naming the recording when it holds none of the sensor's."""
    captures = session.captures(sensor)
    if recording is None:
        return captures
    kept = [c for c in captures if c.meta.get(RECORDING_META_KEY) == recording]
    if not kept:
        raise InputError(f"recording {recording!r} holds no captures of {sensor}: record both sensors together "
                         "first, or measure every capture", "recording")
    return kept


def _camera_poses(session: Session, camera: str, recording: str | None) -> tuple[np.ndarray, np.ndarray]:
    """A camera's capture times (s) and board poses ``T_camera_board`` (K, 4, 4) where it saw the board."""
    intrinsics = session.rig.get(camera).intrinsics
    if intrinsics is None:
        raise InputError(f"{camera} has no intrinsics yet: solve and accept them first", camera)
    board = session_plane_board(session, "a time offset")
    captures = [c for c in _captures(session, camera, recording) if c.detection is not None]
    detections = [Detection.from_dict(c.detection) for c in captures]
    times, poses = camera_board_poses(intrinsics, board, np.array([c.timestamp_s for c in captures]), detections)
    if len(times) < 2:
        raise InputError(f"{camera} has {len(times)} capture(s) with the board; capture the board carried through "
                         "both views first", camera)
    return times, poses


def check_pair(session: Session, sensor_a: str, sensor_b: str, recording: str | None = None) -> None:
    """:class:`InputError` (404 for a sensor the rig lacks) unless the two sensors are a pair this measures (and
    ``recording``, when given, holds captures of both)."""
    kinds = (session.rig.get(sensor_a).kind, session.rig.get(sensor_b).kind)
    if sensor_a == sensor_b or kinds not in PAIRS:
        raise InputError(f"{sensor_a} ({kinds[0]}) and {sensor_b} ({kinds[1]}): time offsets are measured between "
                         f"{SUPPORTED}; name the camera first. A camera or LiDAR against an IMU is the camera-IMU or "
                         "LiDAR-IMU calibration", "reference")
    if kinds[0] == "camera" and session.rig.get(sensor_a).intrinsics is None:
        raise InputError(f"{sensor_a} has no intrinsics yet: solve and accept them first", sensor_a)
    for sensor in (sensor_a, sensor_b) if recording is not None else ():
        _captures(session, sensor, recording)


def _odometry_signal(session: Session, lidar: str, recording: str | None, progress: ProgressCallback
                     ) -> MotionSignal:
    """A LiDAR's angular rates from its captures' odometry (the rig turned in a static scene)."""
    captures = sorted(_captures(session, lidar, recording), key=lambda c: c.timestamp_s)
    if not 20 <= len(captures) <= MAX_SCANS:
        raise InputError(f"{lidar} holds {len(captures)} scans; lining its clock up by its odometry needs 20 to "
                         f"{MAX_SCANS}, taken while the rig turns in a static scene", lidar)
    poses, _ = scan_poses([session.capture_cloud(lidar, c.id)[0] for c in captures], progress)
    return orientation_rate_signal(lidar, np.array([c.timestamp_s for c in captures]), poses[:, :3, :3])


def signals(session: Session, sensor_a: str, sensor_b: str, progress: ProgressCallback = no_progress, *,
            max_offset_s: float = 0.5, recording: str | None = None) -> tuple[MotionSignal, MotionSignal]:
    """The two sensors' motion signals from their captures, or from those of ``recording`` alone (:func:`check_pair`
    first); a 2D scanner's sweep is fitted with offsets within ``±max_offset_s`` (s)."""
    check_pair(session, sensor_a, sensor_b, recording)
    if session.rig.get(sensor_a).kind == "lidar3d":
        return (_odometry_signal(session, sensor_a, recording, lambda f, m: progress(0.5 * f, m)),
                _odometry_signal(session, sensor_b, recording, lambda f, m: progress(0.5 + 0.5 * f, m)))
    t_a, T_a_board = _camera_poses(session, sensor_a, recording)
    if session.rig.get(sensor_b).kind == "camera":
        t_b, T_b_board = _camera_poses(session, sensor_b, recording)
        # each camera's rotation relative to the board (R_board_camera), so the rates are in the camera's axes
        return (orientation_rate_signal(sensor_a, t_a, np.transpose(T_a_board[:, :3, :3], (0, 2, 1))),
                orientation_rate_signal(sensor_b, t_b, np.transpose(T_b_board[:, :3, :3], (0, 2, 1))))
    captures = _captures(session, sensor_b, recording)
    scans = [session.capture_cloud(sensor_b, c.id)[0] for c in captures]
    scan_t_s = np.array([c.timestamp_s for c in captures])
    T_camera_lidar = session.rig.T_a_b(sensor_a, sensor_b)
    planar = session.rig.get(sensor_b).kind == "lidar2d"
    if planar and any(len(points) for points in scans) and not planar_scans(scans, sensor_b):
        raise InputError(f"{sensor_b} is a 2D scanner (lidar2d) but its captures hold points off its scan plane "
                         "(z != 0); if it is a 3D LiDAR, set its kind to lidar3d", sensor_b)
    return _camera_lidar_signals((sensor_a, sensor_b), session_plane_board(session, "a time offset"), t_a, T_a_board,
                                 scan_t_s, scans, T_camera_lidar, planar, max_offset_s, progress)


def _camera_lidar_signals(names: tuple[str, str], board: BoardSpec, camera_t_s: np.ndarray,
                          T_camera_boards: np.ndarray, scan_t_s: np.ndarray, scans: list[np.ndarray],
                          T_camera_lidar: np.ndarray, planar: bool, max_offset_s: float,
                          progress: ProgressCallback) -> tuple[MotionSignal, MotionSignal]:
    """A camera's and a LiDAR's signals (``names``: theirs) from the camera's board poses and the LiDAR's scans: the
    board's line in the scan plane for a 2D scanner (``planar``, its sweep fitted with offsets within
    ``±max_offset_s``), else the board's normal."""
    if planar:
        return scan_line_signals(*names, board, scan_t_s, scans, camera_t_s, T_camera_boards, T_camera_lidar,
                                 max_offset_s, progress)
    return (board_normal_signal(names[0], camera_t_s, T_camera_boards),
            lidar_signal(names[1], board, scan_t_s, scans, camera_t_s, T_camera_boards, T_camera_lidar, progress))


def solve_files(camera_path: Path, corners: Path, scans: Path, board: str, T_camera_lidar: np.ndarray,
                search: TimeOffsetSettings | None = None,
                progress: ProgressCallback = no_progress) -> TimeOffsetResult:
    """``t_lidar = t_camera + offset`` from files: a camera_info YAML, the board's corners (a detections CSV, or a
    folder of images named by their time stamps in ns), a folder of clouds named by their time stamps in ns (a 3D
    LiDAR's, or a 2D scanner's when every point is at z = 0: then the board's line in the scan plane is lined up,
    :mod:`.scan_line`), and the initial ``T_camera_lidar`` (4x4, m) that places the board in the clouds;
    :class:`InputError` naming the file at fault."""
    camera, _ = load_camera_info(camera_path)
    spec = BoardSpec.parse(board)
    if corners.is_dir():
        observations = detect_image_folder(corners, board, lambda f, m: progress(0.3 * f, m))
    else:
        observations = read_detections_csv(corners)
        check_board_points(observations, board, str(corners))
    poses, rms = board_poses(camera, observations)
    found = np.isfinite(rms)
    times, poses = observations.t_s[found], poses[found]
    if len(times) < 2:
        raise InputError(f"the board's pose was found in {len(times)} frame(s)", str(corners))
    scan_times, clouds = read_scan_folder(scans)
    a, b = _camera_lidar_signals(("camera", "lidar"), spec, times, poses, scan_times, clouds, T_camera_lidar,
                                 planar_scans(clouds, str(scans)), (search or TimeOffsetSettings()).max_offset_s,
                                 lambda f, m: progress(0.3 + 0.5 * f, m))
    return solve_time_offset(a, b, search, lambda f, m: progress(0.8 + 0.2 * f, m))


def solve_session(session: Session, sensor_a: str, sensor_b: str, search: TimeOffsetSettings | None = None, *,
                  recording: str | None = None, progress: ProgressCallback = no_progress) -> str:
    """Measure ``t_b = t_a + offset`` from the session's captures (of ``recording`` alone, when given) and keep the
    result under ``sensor_b``; its id."""
    a, b = signals(session, sensor_a, sensor_b, lambda f, m: progress(0.7 * f, m),
                   max_offset_s=(search or TimeOffsetSettings()).max_offset_s, recording=recording)
    result = solve_time_offset(a, b, search, lambda f, m: progress(0.7 + 0.3 * f, m))
    of = "" if recording is None else f" of {recording}"
    return session.add_result(sensor_b, result.to_record(),
                              inputs=[f"{sensor_a} captures{of}", f"{sensor_b} captures{of}"])


def time_offset_results(session: Session, sensor: str) -> list[dict[str, Any]]:
    """The sensor's stored time-offset results, oldest first (the command's JSON with the id)."""
    session.rig.get(sensor)
    keys = ("sensor_a", "sensor_b", "time_offset_s", "std", "R_a_b", "samples", "verdict", "seconds", "halves")
    return [{"result_id": record["id"]} | {k: record.get(k) for k in keys} for record in session.results(sensor, KIND)]
