"""viser's own port, guarded: the studio's page and websocket answer only requests that may drive the studio.

* In token mode viser listens on 127.0.0.1 behind the API's token-checked proxy (:mod:`backend.api.viewer_proxy`),
  but any local process could open that port directly. A per-process secret, which only the proxy knows and sends
  as the :data:`SECRET_HEADER` header, is required on every HTTP request and websocket handshake.
* Otherwise (the studio served on loopback without a token) the :mod:`backend.api.origin` Host and Origin checks
  run there, so a foreign web page can neither open the studio's websocket nor read its page by DNS rebinding.

Where the hook is: viser 1.1 serves its client files and its websocket from one ``websockets.asyncio.server.serve``
call (``viser/infra/_infra.py``) with ``process_request=`` its file server, which sees every HTTP request and
every websocket handshake, and ``ViserServer`` binds and starts inside its constructor, with no way to pass
options through. So :func:`start_viewer` builds the ``ViserServer`` while ``serve`` is wrapped to put our check in
front of viser's ``process_request``. ``ViserServer.__init__`` returns only once ``serve`` has bound its port
(viser waits on a semaphore), so the wrapper is in place for exactly that call and removed before anything else
runs; a lock keeps two constructions from overlapping.
"""

from __future__ import annotations

import contextlib
import functools
import hmac
import http
import os
import secrets
import threading
from collections.abc import Callable, Iterator
from typing import Any

import viser
import websockets.asyncio.server
from websockets.asyncio.server import ServerConnection
from websockets.http11 import Request, Response

from backend.api import origin

SECRET_HEADER = "X-Calib-Viewer-Secret"
"""The header by which the proxy proves itself to the viewer in token mode."""

_PATCH_LOCK = threading.Lock()

Check = Callable[[ServerConnection, Request], str | None]
"""A refusal message for a request to the viewer's port, or None to let viser answer it."""


def new_secret() -> str:
    return secrets.token_urlsafe(32)


def secret_check(secret: str) -> Check:
    """Refuse every request that does not carry ``secret`` in :data:`SECRET_HEADER`."""
    expected = secret.encode()

    def check(connection: ServerConnection, request: Request) -> str | None:
        presented = request.headers.get(SECRET_HEADER, "").encode()
        if hmac.compare_digest(expected, presented):
            return None
        return "the studio is served through the API's /studio/ page with the token; open the URL the server printed"

    return check


def origin_check(bind_host: str) -> Check:
    """Refuse requests whose Host, or whose Origin on a websocket handshake, is not the viewer's own
    (:class:`~backend.api.origin.OriginPolicy` of ``bind_host`` and the port the viewer is bound to)."""

    @functools.cache
    def policy(port: int) -> origin.OriginPolicy:
        return origin.OriginPolicy.for_server(bind_host, (port,))

    def check(connection: ServerConnection, request: Request) -> str | None:
        websocket = request.headers.get("Upgrade", "").lower() == "websocket"
        refused = origin.refusal(policy(connection.local_address[1]), "GET", request.headers, websocket=websocket)
        return None if refused is None else refused[0]

    return check


@contextlib.contextmanager
def _checked_serve(check: Check) -> Iterator[None]:
    """While inside, ``websockets.asyncio.server.serve`` runs ``check`` before the caller's ``process_request``."""
    original = websockets.asyncio.server.serve

    def serve(*args: Any, process_request: Callable[..., Any] | None = None, **kwargs: Any) -> Any:
        def guarded(connection: ServerConnection, request: Request) -> Response | None:
            refused = check(connection, request)
            if refused is not None:
                return connection.respond(http.HTTPStatus.FORBIDDEN, refused + "\n")
            return process_request(connection, request) if process_request is not None else None

        return original(*args, process_request=guarded, **kwargs)

    with _PATCH_LOCK:
        websockets.asyncio.server.serve = serve
        try:
            yield
        finally:
            websockets.asyncio.server.serve = original


def start_viewer(host: str, port: int, check: Check) -> viser.ViserServer:
    """A started ``ViserServer`` on ``host:port`` (the next free port if taken) that answers only what ``check``
    lets through. viser's banner is not printed: it names the viewer's own address, which behind the token proxy is
    not the one to open, and the studio's URL must be the first line a user sees."""
    with _checked_serve(check), open(os.devnull, "w") as devnull, contextlib.redirect_stdout(devnull):
        return viser.ViserServer(host=host, port=port, verbose=False)
