"""Sessions, their board and their sensors."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from backend.api.routes import deps
from backend.api.schemas import BoardUpdate, SensorCreate, SessionCreate
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
    session.add_sensor(Frame(body.name, body.parent, T, kind=body.kind, device=body.device,
                             mount_sigma=body.mount_sigma))
    return session.info()
