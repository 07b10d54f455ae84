"""Reverse proxy for the viser studio at ``/studio/``, behind the API's token check.

When the server is bound beyond loopback, viser listens on 127.0.0.1 only and the
browser reaches it through the FastAPI app:

* ``GET /studio/{path}`` is fetched from ``http://127.0.0.1:<viewer_port>/{path}``
  (the token middleware of :func:`backend.api.app.create_app` has already run;
  a first load with ``?token=`` sets the ``calib_token`` cookie).
* The websocket is relayed to ``ws://127.0.0.1:<viewer_port>/``. The viser client
  opens its websocket at the page URL without query and trailing slash
  (``/studio/?token=T`` connects to ``ws://HOST:PORT/studio``) unless the page has
  ``?websocket=<url>``, so ``/studio``, ``/studio/`` and ``/studio/...`` all accept
  websockets. The HTTP middleware does not run for websockets, so the token (the
  cookie, ``?token=`` or a bearer header) is checked here; a wrong one is refused
  before the handshake completes (close code 1008, an HTTP 403 to the client).
* Every request to the viewer carries the per-process secret in
  :data:`backend.api.viewer_guard.SECRET_HEADER`: the viewer (started by
  :func:`backend.api.viewer_guard.start_viewer` with ``secret_check``) refuses anyone else.
"""

from __future__ import annotations

import asyncio
from urllib.parse import quote

import httpx
import websockets.asyncio.client
import websockets.exceptions
from fastapi import FastAPI, Request, WebSocket
from fastapi.responses import RedirectResponse, Response
from starlette.requests import HTTPConnection
from starlette.websockets import WebSocketState
from websockets.typing import Subprotocol

from backend.api import auth
from backend.api.viewer_guard import SECRET_HEADER

MAX_MESSAGE_BYTES = 50 * 1024 * 1024
"""Same limit as viser's own websocket server."""

_HOP_BY_HOP = frozenset({"connection", "keep-alive", "proxy-authenticate", "proxy-authorization", "te",
                         "trailer", "transfer-encoding", "upgrade", "content-length", "date", "server"})
_FORWARDED_REQUEST_HEADERS = ("accept", "accept-encoding", "accept-language", "if-none-match", "if-modified-since")


def _presented_token(conn: HTTPConnection) -> str | None:
    """The token a websocket handshake carries: bearer header, ``?token=`` or the cookie."""
    header = conn.headers.get("authorization", "")
    if header.lower().startswith("bearer "):
        return header[7:].strip()
    return conn.query_params.get("token") or conn.cookies.get(auth.COOKIE)


def mount_viewer_proxy(app: FastAPI, viewer_port: int, token: str | None, viewer_secret: str) -> None:
    """Serve the viser studio on ``viewer_port`` (127.0.0.1) at ``/studio/`` of ``app``.

    ``token`` must be the one given to :func:`backend.api.app.create_app`: the HTTP
    routes rely on its middleware, the websocket routes check it themselves.
    ``viewer_secret`` is the one the viewer was started with, sent on every request to it.
    """
    upstream_http = f"http://127.0.0.1:{viewer_port}"
    upstream_ws = f"ws://127.0.0.1:{viewer_port}/"
    secret = {SECRET_HEADER: viewer_secret}

    @app.get("/studio", include_in_schema=False)
    def studio_redirect(request: Request) -> RedirectResponse:
        query = request.url.query
        return RedirectResponse("/studio/" + (f"?{query}" if query else ""))

    @app.get("/studio/{path:path}", include_in_schema=False)
    async def studio_asset(path: str, request: Request) -> Response:
        headers = {name: request.headers[name] for name in _FORWARDED_REQUEST_HEADERS if name in request.headers}
        headers |= secret
        async with httpx.AsyncClient(timeout=30.0) as client:
            upstream = client.build_request("GET", f"{upstream_http}/{quote(path)}", headers=headers)
            try:
                response = await client.send(upstream, stream=True)
            except httpx.HTTPError as exc:
                return Response(f"studio viewer unreachable: {exc}", status_code=502, media_type="text/plain")
            try:
                # Raw bytes: the body stays gzip-encoded when the browser accepted gzip.
                body = b"".join([chunk async for chunk in response.aiter_raw()])
            finally:
                await response.aclose()
        passed = {k: v for k, v in response.headers.items() if k.lower() not in _HOP_BY_HOP}
        return Response(body, status_code=response.status_code, headers=passed)

    async def studio_websocket(websocket: WebSocket) -> None:
        if not auth.token_ok(token, _presented_token(websocket)):
            await websocket.close(code=1008)  # before accept: the handshake gets HTTP 403
            return
        offered = [Subprotocol(p) for p in websocket.scope.get("subprotocols", []) if p.startswith("viser-v")]
        try:
            viewer = await websockets.asyncio.client.connect(
                upstream_ws, subprotocols=offered or None, additional_headers=secret, max_size=MAX_MESSAGE_BYTES,
                compression=None)
        except (OSError, websockets.exceptions.WebSocketException):
            await websocket.close(code=1011)
            return
        async with viewer:
            await websocket.accept(subprotocol=viewer.subprotocol)
            await _relay(websocket, viewer)

    for route in ("/studio", "/studio/", "/studio/{path:path}"):
        app.add_api_websocket_route(route, studio_websocket)


async def _relay(browser: WebSocket, viewer: websockets.asyncio.client.ClientConnection) -> None:
    """Copy text and binary messages both ways until either side closes; then close both."""

    async def browser_to_viewer() -> None:
        while True:
            message = await browser.receive()
            if message["type"] == "websocket.disconnect":
                return
            data = message.get("bytes")
            await viewer.send(data if data is not None else message.get("text") or "")

    async def viewer_to_browser() -> None:
        async for data in viewer:
            if isinstance(data, bytes):
                await browser.send_bytes(data)
            else:
                await browser.send_text(data)

    tasks = [asyncio.create_task(browser_to_viewer()), asyncio.create_task(viewer_to_browser())]
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in tasks:
            task.cancel()
        # Errors of either side (a closed connection) just end the relay.
        await asyncio.gather(*tasks, return_exceptions=True)
        await viewer.close()
        if browser.client_state == WebSocketState.CONNECTED and browser.application_state == WebSocketState.CONNECTED:
            try:
                await browser.close()
            except (RuntimeError, OSError):
                pass  # the browser went away meanwhile
