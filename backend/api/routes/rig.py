"""The session's rig as one fused tree: accept any result, preview an accept, revert an edge."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from backend.api.routes import deps
from backend.api.schemas import AcceptRequest, PreviewRequest, RevertRequest
from backend.calib.rig import service

router = APIRouter(tags=["rig"])


@router.get("/sessions/{name}/rig/tree")
def rig_tree(session: deps.SessionDep) -> dict[str, Any]:
    """The fused tree (the ``calib-studio rig --json`` object) with the problems the user must look at."""
    tree = service.solve_rig(session)
    return tree.summary() | {"problems": tree.problems()}


@router.post("/sessions/{name}/rig/preview")
def preview(body: PreviewRequest, session: deps.SessionDep) -> dict[str, Any]:
    """What accepting ``result_id`` would move, against the frames' sigma, and what would disagree; nothing is
    written."""
    return service.preview(session, body.result_id, body.revert).to_dict()


@router.post("/sessions/{name}/accept")
def accept(body: AcceptRequest, session: deps.SessionDep) -> dict[str, Any]:
    """Accept any result (intrinsics, a transform, a multi-camera solve, a sweep geometry) and re-fit the rig."""
    return service.accept(session, body.result_id, confirm=body.confirm, revert=body.revert).to_dict()


@router.post("/sessions/{name}/rig/revert")
def revert(body: RevertRequest, session: deps.SessionDep) -> dict[str, Any]:
    """Empty one accepted slot (its result stays in the history) and re-fit the rig without its edges."""
    return service.revert(session, body.slot).to_dict()
