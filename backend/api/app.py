"""The FastAPI application: REST API, OpenAPI docs and downloads.

Routers are thin: they validate with pydantic, call :mod:`backend.services` and
turn :class:`InputError` into a 4xx JSON body ``{"error": {"message", "input"}}``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, RedirectResponse
from fastapi_offline import FastAPIOffline
from starlette.datastructures import Headers
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Receive, Scope, Send
from starlette.websockets import WebSocket

from backend.api import auth, origin
from backend.api.client_watch import ClientWatch
from backend.api.routes import camera_imu as camera_imu_routes
from backend.api.routes import depth_network as depth_network_routes
from backend.api.routes import exports, intrinsics, lidar, lidar_camera, multicam, recordings, rig, sessions, sweep
from backend.api.routes import jobs as job_routes
from backend.api.routes import lidar_imu as lidar_imu_routes
from backend.api.routes import report as report_routes
from backend.api.routes import time_offset as time_offset_routes
from backend.api.routes.targets import router as targets_router
from backend.api.routes.test_field import router as test_field_router
from backend.core.errors import CancelledError, InputError
from backend.services.jobs import JobRunner
from backend.store.session import SessionStore


@dataclass
class AppState:
    """What every route needs, held on ``app.state.studio``."""

    store: SessionStore
    jobs: JobRunner
    token: str | None = None
    studio_url: str | None = None
    """Where ``/`` sends a browser: the viser studio page."""


def error_response(status: int, message: str, input: str | None = None) -> JSONResponse:
    return JSONResponse(status_code=status, content={"error": {"message": message, "input": input}})


class OriginGuard:
    """ASGI middleware: :func:`backend.api.origin.refusal` on every HTTP request and websocket handshake.

    A refused request gets a 403 ``{"error": {"message", "input": "Host" | "Origin"}}``; a refused websocket is
    closed before its handshake completes (an HTTP 403 to the client). Runs before the token check.
    """

    def __init__(self, app: ASGIApp, policy: origin.OriginPolicy | None) -> None:
        self.app = app
        self.policy = policy

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] in ("http", "websocket"):
            websocket = scope["type"] == "websocket"
            refused = origin.refusal(self.policy, scope.get("method", "GET"), Headers(scope=scope), websocket)
            if refused is not None:
                if websocket:
                    await WebSocket(scope, receive, send).close(code=1008)
                else:
                    await error_response(403, *refused)(scope, receive, send)
                return
        await self.app(scope, receive, send)


def create_app(store: SessionStore | Path, jobs: JobRunner | None = None, token: str | None = None,
               studio_url: str | None = None, origins: origin.OriginPolicy | None = None) -> FastAPI:
    """Build the app over a session store. ``token`` set means every call must present it.

    ``origins`` are the hosts and ports the served app answers to (:class:`~backend.api.origin.OriginPolicy`);
    None, for an app used in process (a test client), checks only that a state-changing request's ``Origin``
    is its own ``Host``.
    """
    if not isinstance(store, SessionStore):
        store = SessionStore(Path(store))
    # Swagger UI and ReDoc from the package's own copies: /docs works offline (no CDN).
    app = FastAPIOffline(title="Calibration Studio API", version="0.1.0",
                         description="Sessions, captures, solves and exports of Calibration Studio.",
                         swagger_ui_parameters={"validatorUrl": None})
    app.state.studio = AppState(store, jobs or JobRunner(), token, studio_url)

    @app.middleware("http")
    async def require_token(request: Request, call_next):
        presented = auth.presented_token(request)
        if not auth.token_ok(token, presented):
            return error_response(401, "missing or wrong token; open the URL the server printed, "
                                       "or send 'Authorization: Bearer <token>'", "token")
        response = await call_next(request)
        if token and request.query_params.get("token"):
            response.set_cookie(auth.COOKIE, token, httponly=True, samesite="strict")
        return response

    app.add_middleware(ClientWatch)
    app.add_middleware(OriginGuard, policy=origins)  # added last: runs first

    @app.exception_handler(InputError)
    async def input_error(request: Request, exc: InputError) -> JSONResponse:
        return error_response(exc.status_code, exc.message, exc.input)

    @app.exception_handler(CancelledError)
    async def client_left(request: Request, exc: CancelledError) -> JSONResponse:
        # 499 (nginx's "client closed request"): no one reads it; it keeps the access log honest.
        return error_response(499, str(exc), request.url.path)

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        return error_response(exc.status_code, str(exc.detail), request.url.path)

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        first = exc.errors()[0]
        field = ".".join(str(p) for p in first["loc"] if p != "body")
        if not field:  # a check of the whole body (two spellings of one pose): its message names the fields
            return error_response(422, f"body: {first['msg']}", "body")
        return error_response(422, f"field '{field}': {first['msg']}", field)

    @app.get("/api/health", tags=["meta"])
    def health() -> dict[str, str]:
        return {"status": "ok"}

    @app.get("/", include_in_schema=False)
    def root() -> RedirectResponse:
        return RedirectResponse(studio_url or "/docs")

    for router in (sessions.router, intrinsics.router, lidar.router, lidar_camera.router, multicam.router,
                   sweep.router, recordings.router, job_routes.router, exports.router, rig.router, targets_router,
                   test_field_router, report_routes.router, depth_network_routes.router, camera_imu_routes.router,
                   time_offset_routes.router, lidar_imu_routes.router):
        app.include_router(router, prefix="/api")
    return app
