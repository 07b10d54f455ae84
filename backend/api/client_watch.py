"""Stop a request's work once its client has gone.

An upload is read and checked in FastAPI's thread pool, file by file; a client that gives up (closes the tab,
kills ``curl``) would otherwise leave the server decoding and detecting the rest for nobody. :class:`ClientWatch`
listens for the ASGI ``http.disconnect`` once the request's body is in, and until its response starts; the
:func:`client_progress` dependency hands the route a progress callback that raises
:class:`~backend.core.errors.CancelledError` at the next file once the client has left. The services stop there
as they stop for a cancelled job: nothing of the batch is stored.
"""

from __future__ import annotations

import asyncio
import logging
from threading import Event
from typing import Annotated

from fastapi import Depends, Request
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from backend.core.errors import CancelledError
from backend.core.result import ProgressCallback

log = logging.getLogger(__name__)

_STATE_KEY = "client_gone"
"""The request's :class:`threading.Event`, in the ASGI scope's ``state`` (Starlette's ``request.state``)."""


class ClientWatch:
    """ASGI middleware: sets the request's ``client_gone`` event when its client disconnects before the response.

    The watch starts only after the last chunk of the body was received, so it never takes a body chunk from the
    route, and stops when the response starts.
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        gone = Event()
        scope.setdefault("state", {})[_STATE_KEY] = gone
        watch: asyncio.Task | None = None

        async def listen() -> None:
            while (await receive())["type"] != "http.disconnect":
                pass
            gone.set()

        async def receive_body() -> Message:
            nonlocal watch
            message = await receive()
            if message["type"] == "http.disconnect":
                gone.set()
            elif message["type"] == "http.request" and not message.get("more_body", False) and watch is None:
                watch = asyncio.create_task(listen())
            return message

        async def send_and_stop_watching(message: Message) -> None:
            if message["type"] == "http.response.start" and watch is not None:
                watch.cancel()
            await send(message)

        try:
            await self.app(scope, receive_body, send_and_stop_watching)
        finally:
            if watch is not None:
                watch.cancel()


def client_progress(request: Request) -> ProgressCallback:
    """A progress callback for a route's service call: raises :class:`CancelledError` once the client has left."""
    gone: Event | None = request.scope.get("state", {}).get(_STATE_KEY)
    what = f"{request.method} {request.url.path}"

    def progress(fraction: float, message: str) -> None:
        if gone is not None and gone.is_set():
            log.warning("stopped %s at %.0f %% (%s): the client left", what, 100 * fraction, message)
            raise CancelledError(f"the client left {what}; stopped, nothing of it was stored")

    return progress


ClientProgressDep = Annotated[ProgressCallback, Depends(client_progress)]
