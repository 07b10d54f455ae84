"""Sessions, their targets (the board or test field and its survey, the V-target) and their sensors: add, edit,
remove (and restore) a sensor."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, File, Query, UploadFile

from backend.api.routes import deps
from backend.api.schemas import BoardUpdate, SensorCreate, SensorUpdate, SessionCreate, TestFieldUpdate, VTargetUpdate
from backend.api.uploads import UploadRoute, file_name, upload_limit
from backend.calib.rig import service as rig_service
from backend.core.errors import InputError
from backend.core.limits import MAX_TEXT_UPLOAD_MB
from backend.core.rig import Frame
from backend.core.targets import parse_target
from backend.core.test_field import MAX_SURVEY_BYTES, SESSION_SURVEY, TestField
from backend.core.v_target import VTarget
from backend.store.rig_io import rig_to_model

router = APIRouter(tags=["sessions"], route_class=UploadRoute)


@router.get("/sessions")
def list_sessions(store: deps.StoreDep) -> list[dict[str, Any]]:
    """Every session; one that cannot be opened is listed with ``broken``: its reason (the others still load)."""
    return store.listing()


@router.post("/sessions", status_code=201)
def create_session(body: SessionCreate, store: deps.StoreDep) -> dict[str, Any]:
    """Create a session with a board (a test field needs its survey uploaded first: create the session without a
    board, upload the survey, then set the board)."""
    if body.board and body.board.strip().startswith("testfield:"):
        raise InputError(f"a new session holds no survey yet; create it without a board, upload the survey "
                         f"(PUT /api/sessions/{body.name}/survey), then set {body.board!r} as its board", "board")
    board = str(parse_target(body.board)) if body.board else None
    return store.create(body.name, board=board, title=body.title).info()


@router.get("/sessions/{name}")
def get_session(session: deps.SessionDep) -> dict[str, Any]:
    return session.info()


@router.put("/sessions/{name}/board")
def set_board(body: BoardUpdate, session: deps.SessionDep) -> dict[str, Any]:
    """Set the board, or a test field (``testfield:DICT:MARKER:survey.csv``: the session's uploaded survey)."""
    session.set_board(str(parse_target(body.board, session.path)))
    return session.info()


@router.put("/sessions/{name}/survey")
@upload_limit(MAX_TEXT_UPLOAD_MB, "file")
def upload_survey(file: Annotated[UploadFile, File(description="the survey: a line of id, X, Y, Z (m) per marker")],
                  session: deps.SessionDep) -> dict[str, Any]:
    """Keep a test field's survey as the session's ``survey.csv`` (the one it replaces is kept under ``surveys/``);
    a file that does not read as a survey is refused naming its line and field, and changes nothing."""
    name = file_name(file, "file", SESSION_SURVEY)
    file.file.seek(0)
    session.set_survey(file.file.read(MAX_SURVEY_BYTES + 1), name)
    return session.info()


@router.put("/sessions/{name}/v-target")
def set_v_target(body: VTargetUpdate, session: deps.SessionDep) -> dict[str, Any]:
    """Set the V-target the vtarget LiDAR-camera method solves with."""
    session.set_v_target(str(VTarget.parse(body.v_target)))
    return session.info()


@router.put("/sessions/{name}/test-field")
def set_test_field(body: TestFieldUpdate, session: deps.SessionDep) -> dict[str, Any]:
    """Set a wall test field beside the board (``testfield:DICT:MARKER:survey.csv``, the session's uploaded survey),
    for the cameras' exterior orientation; the board stays the camera target of the other steps."""
    session.set_test_field(str(TestField.parse(body.test_field, session.path, field="test_field")))
    return session.info()


@router.get("/sessions/{name}/rig")
def get_rig(session: deps.SessionDep) -> dict[str, Any]:
    return rig_to_model(session.rig).model_dump()


@router.post("/sessions/{name}/sensors", status_code=201)
def add_sensor(body: SensorCreate, session: deps.SessionDep) -> dict[str, Any]:
    T = body.pose.matrix()
    rig_service.add_sensor(session, Frame(body.name, body.parent, T, kind=body.kind, device=body.device,
                                          mount_sigma=body.mount_sigma), connected=body.connected)
    return session.info()


Preview = Annotated[bool, Query(description="only say what would change and move; nothing is written")]


@router.patch("/sessions/{name}/sensors/{sensor}")
def edit_sensor(sensor: str, body: SensorUpdate, session: deps.SessionDep, preview: Preview = False) -> dict[str, Any]:
    """Change a sensor's parent, mounting guess, mount sigma or device; the rig is re-fitted (``moves`` says what
    moved, ``conflicts`` what disagrees)."""
    given = body.model_fields_set
    edit = rig_service.SensorEdit(
        parent=body.parent, T_mount=None if body.pose is None else body.pose.matrix(),
        mount_sigma=body.mount_sigma if "mount_sigma" in given else rig_service.KEEP, device=body.device)
    return rig_service.edit_sensor(session, sensor, edit, preview=preview).to_dict()


@router.delete("/sessions/{name}/sensors/{sensor}")
def remove_sensor(sensor: str, session: deps.SessionDep, preview: Preview = False) -> dict[str, Any]:
    """Remove a sensor: its accepted slots are emptied (``emptied``), the rig is re-fitted without it (``moves``) and
    its captures and results are kept aside, restorable (``removal.id``). 409 while other frames hang from it."""
    return rig_service.remove_sensor(session, sensor, preview=preview).to_dict()


@router.get("/sessions/{name}/removed")
def removed_sensors(session: deps.SessionDep) -> list[dict[str, Any]]:
    """The sensors removed and not restored, oldest first, with what each kept."""
    return session.removed()


@router.post("/sessions/{name}/removed/{removal}/restore")
def restore_sensor(removal: str, session: deps.SessionDep, preview: Preview = False) -> dict[str, Any]:
    """Put a removed sensor back with its captures and the accepted results it took with it (``restored``; those
    that cannot come back are named in ``not_restored``)."""
    return rig_service.restore_sensor(session, removal, preview=preview).to_dict()
