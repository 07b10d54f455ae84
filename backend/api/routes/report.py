"""The session's calibration report (one self-contained HTML file)."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import HTMLResponse

from backend.api.routes import deps
from backend.services.report import render_report

router = APIRouter(tags=["report"])


@router.get("/sessions/{name}/report", response_class=HTMLResponse,
            responses={200: {"content": {"text/html": {}}, "description": "the report, as a download"}})
def report(session: deps.SessionDep) -> HTMLResponse:
    """Every sensor and rig edge of the session with its method, data, sigma, verdict, cross-checks and residual
    plots, the observation graph and the rig drawn; no external request, printable to PDF."""
    return HTMLResponse(render_report(session),
                        headers={"Content-Disposition": f'attachment; filename="{session.name}-report.html"'})
