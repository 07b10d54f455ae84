"""Sessions, their board and their sensors: add, edit, remove (and restore) a sensor."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query

from backend.api.routes import deps
from backend.api.schemas import BoardUpdate, SensorCreate, SensorUpdate, SessionCreate
from backend.calib.rig import service as rig_service
from backend.core.boards import BoardSpec
from backend.core.rig import Frame
from backend.store.rig_io import rig_to_model

router = APIRouter(tags=["sessions"])


@router.get("/sessions")
def list_sessions(store: deps.StoreDep) -> list[dict[str, Any]]:
    """Every session; one that cannot be opened is listed with ``broken``: its reason (the others still load)."""
    return store.listing()


@router.post("/sessions", status_code=201)
def create_session(body: SessionCreate, store: deps.StoreDep) -> dict[str, Any]:
    board = str(BoardSpec.parse(body.board)) if body.board else None
    return store.create(body.name, board=board, title=body.title).info()


@router.get("/sessions/{name}")
def get_session(session: deps.SessionDep) -> dict[str, Any]:
    return session.info()


@router.put("/sessions/{name}/board")
def set_board(body: BoardUpdate, session: deps.SessionDep) -> dict[str, Any]:
    session.set_board(str(BoardSpec.parse(body.board)))
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
