"""What every problem's service does with a session: check a sensor's kind, read the board, keep a cloud,
look up a stored result of the right kind.

Each problem's ``service.py`` builds on these so that a camera, a LiDAR or a result is refused with the same
words everywhere (the API turns the :class:`~backend.core.errors.InputError` into a 4xx naming the input).
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from backend.calib.intrinsics.flex import solved_board
from backend.core.boards import BoardSpec
from backend.core.errors import InputError
from backend.core.rig import Rig
from backend.core.targets import CameraTarget, parse_target
from backend.core.test_field import SESSION_SURVEY, TestField
from backend.core.v_target import VTarget
from backend.devices.base import Sample
from backend.devices.cloud_files import CLOUD_EXTENSIONS, read_cloud
from backend.store.schema import CaptureRecord
from backend.store.session import Session

LIDAR_KINDS = ("lidar3d", "lidar2d", "depth")
"""Sensor kinds that give point clouds."""


def lidar_names(rig: Rig) -> list[str]:
    """The rig's LiDAR and depth sensors, in rig order."""
    return [f.name for f in rig.frames.values() if f.kind in LIDAR_KINDS]


def session_board(session: Session) -> CameraTarget:
    """The session's camera target: a board, or a test field whose survey the session holds."""
    if not session.board:
        raise InputError(f"session {session.name!r} has no board spec yet; set one such as checkerboard:9x6:0.025",
                         "board")
    return parse_target(session.board, session.path)


def session_plane_board(session: Session, use: str) -> BoardSpec:
    """The session's board for ``use`` (e.g. "the target method"), which a test field cannot serve, bowed as its
    cameras' accepted intrinsics measured it (:func:`measured_board`): a board pose fitted to a flat board where the
    board bows is off by the bow."""
    board = session_board(session)
    if not isinstance(board, BoardSpec):
        raise InputError(f"the session's target is a test field ({session.board}); {use} needs a board: set a "
                         "checkerboard or ChArUco spec", "board")
    return measured_board(session, board)


def measured_board(session: Session, board: BoardSpec) -> BoardSpec:
    """``board`` with the flex the session's accepted intrinsics solved for it (``board_flex``): the best determined
    (smallest sigma) when several cameras measured it, flat when none did."""
    measured = [record for record in map(session.result, session.accepted_slots().values())
                if record.get("kind") == "intrinsics" and record.get("board") == str(board)
                and (record.get("board_flex") or {}).get("status") == "solved"]
    if not measured:
        return board
    return solved_board(min(measured, key=lambda record: max(record["board_flex"]["std_mm"])))


def pair_board(session: Session) -> BoardSpec | None:
    """The board a LiDAR-camera pair's image is searched for: the session's, unless it has none or it is a test
    field (a wall the pairs do not show)."""
    board = session_board(session) if session.board else None
    return board if isinstance(board, BoardSpec) else None


def session_test_field(session: Session) -> TestField:
    """The session's wall test field: the one set beside its board (:attr:`Session.test_field`), else its board when
    that is a test field."""
    if session.test_field:
        return TestField.parse(session.test_field, session.path, field="test_field")
    board = session_board(session) if session.board else None
    if not isinstance(board, TestField):
        raise InputError(f"session {session.name!r} has no test field: upload the wall's survey, then set the test "
                         f"field beside the board (testfield:DICT:MARKER:{SESSION_SURVEY}) or make it the board",
                         "test_field")
    return board


def session_v_target(session: Session) -> VTarget:
    """The session's V-target, for the vtarget LiDAR-camera method."""
    if not session.v_target:
        raise InputError(f"session {session.name!r} has no V-target spec yet; set one such as "
                         "vtarget:1.0x0.6:120:3x2:0.15:DICT_4X4_50", "v_target")
    return VTarget.parse(session.v_target)


def check_camera(session: Session, camera: str) -> None:
    """Refuse ``camera`` unless the rig holds it as a camera (a LiDAR has no intrinsics, images or board views)."""
    if session.rig.get(camera).kind != "camera":
        raise InputError(f"sensor {camera!r} is a {session.rig.get(camera).kind}, not a camera", "camera")


def check_lidar(session: Session, sensor: str) -> None:
    """Refuse (naming the sensor) anything but a LiDAR or depth sensor of the rig."""
    kind = session.rig.get(sensor).kind
    if kind not in LIDAR_KINDS:
        raise InputError(f"sensor {sensor!r} is a {kind}, not a LiDAR or depth sensor", "sensor")


def check_imu(session: Session, sensor: str) -> None:
    """:class:`InputError` (404) unless ``sensor`` is an IMU of the session's rig (its IMUs named)."""
    frame = session.rig.frames.get(sensor)
    if frame is None or frame.kind != "imu":
        imus = [f.name for f in session.rig.sensors("imu")]
        raise InputError(f"{sensor!r} is not an IMU of the rig; IMUs: {', '.join(imus) or 'none (add one)'}",
                         "sensor", 404)


def store_cloud(session: Session, sensor: str, sample: Sample, *, device: str, source: str | None = None
                ) -> CaptureRecord:
    """Keep one cloud (live or imported) in the sensor's frame."""
    check_lidar(session, sensor)
    if sample.points is None or len(sample.points) == 0:
        raise InputError(f"{source or device}: the cloud holds no points", source or device)
    return session.add_cloud_capture(sensor, sample.points, sample.intensity, {
        "timestamp_s": sample.timestamp_s, "device": device, "source": source, "meta": sample.storable_meta()})


def read_uploaded_cloud(name: str, data: bytes | Path) -> Sample:
    """An uploaded cloud file's points as a sample (``meta``: the base ``source`` name kept and the points
    dropped as non-finite); ``data`` is the file's bytes or the path it was saved to (an upload streamed to
    disk). Raises :class:`InputError` naming the file when it cannot be read."""
    safe_name = Path(name).name
    if Path(safe_name).suffix.lower() not in CLOUD_EXTENSIONS:
        raise InputError(f"{safe_name}: not a point-cloud file (expected {', '.join(CLOUD_EXTENSIONS)})", safe_name)
    try:
        if isinstance(data, Path):
            cloud = read_cloud(data)
        else:
            with tempfile.TemporaryDirectory() as folder:
                path = Path(folder) / safe_name
                path.write_bytes(data)
                cloud = read_cloud(path)
    except InputError as exc:  # name the upload, not the server's temporary path
        exc.input = safe_name
        raise
    return Sample(0.0, points=cloud.points, intensity=cloud.intensity,
                  meta={"source": safe_name, "dropped_non_finite": cloud.dropped_non_finite})


def result_of(session: Session, kind: str, result_id: str, sensor: str | None = None) -> dict[str, Any]:
    """The stored record ``result_id`` if it is a ``kind`` result (of ``sensor``, when given); else an
    :class:`InputError` naming ``result`` and saying what it is instead."""
    record = session.result(result_id)
    require_kind(record, kind)
    if sensor is not None and record["sensor"] != sensor:
        raise InputError(f"result {result_id} belongs to {record['sensor']}, not {sensor}", "result")
    return record


def require_kind(record: dict[str, Any], kind: str) -> None:
    """Refuse (naming ``result``) a stored record of another kind than ``kind``."""
    if record.get("kind") != kind:
        raise InputError(f"result {record.get('id')} is a {record.get('kind')} result, not {kind}", "result")
