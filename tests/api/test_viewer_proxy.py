"""The viser studio reverse-proxied at ``/studio/`` behind the API token (real servers on 127.0.0.1); the viewer's
own port refuses whoever lacks the proxy's secret."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import httpx
import msgspec
import pytest
import uvicorn
import viser
import websockets.exceptions
from playwright.sync_api import Browser
from viser import _messages
from websockets.sync.client import connect

from backend.api.app import create_app
from backend.api.viewer_guard import SECRET_HEADER, secret_check, start_viewer
from backend.api.viewer_proxy import MAX_MESSAGE_BYTES, mount_viewer_proxy
from tests.conftest import ARTIFACTS, UI_WAIT_MS, poll, wait_frame

TOKEN = "secret"
VIEWER_SECRET = "proxy-only"
SUBPROTOCOL = "viser-v" + viser.__version__
"""What the viser client offers (``WebsocketClientWorker.ts``); viser's server picks any ``viser-v*``."""
CAMERA = msgspec.msgpack.encode(_messages.ViewerCameraMessage(
    wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, 0.0, -2.0), fov=1.0, near=0.01, far=100.0, image_height=480,
    image_width=640, look_at=(0.0, 0.0, 0.0), up_direction=(0.0, -1.0, 0.0)).as_serializable_dict())
"""What the viser client sends first: a pose of its viewer camera."""


@dataclass
class Servers:
    viewer: viser.ViserServer
    api_port: int

    @property
    def base(self) -> str:
        return f"http://127.0.0.1:{self.api_port}"

    @property
    def ws(self) -> str:
        return f"ws://127.0.0.1:{self.api_port}/studio"

    @property
    def direct(self) -> str:
        """The viewer's own port, which only the proxy may use."""
        return f"127.0.0.1:{self.viewer.get_port()}"


@pytest.fixture(scope="module")
def servers(tmp_path_factory: pytest.TempPathFactory, free_port: Callable[[], int]) -> Iterator[Servers]:
    viewer_port = free_port()
    viewer = start_viewer("127.0.0.1", viewer_port, secret_check(VIEWER_SECRET))
    viewer.scene.add_frame("/probe")
    viewer.gui.add_markdown("proxy-ok")

    app = create_app(tmp_path_factory.mktemp("sessions"), token=TOKEN)
    mount_viewer_proxy(app, viewer_port, TOKEN, VIEWER_SECRET)
    api_port = free_port()
    config = uvicorn.Config(app, host="127.0.0.1", port=api_port, log_level="warning",
                            ws_max_size=MAX_MESSAGE_BYTES, ws_per_message_deflate=False)
    api = uvicorn.Server(config)
    thread = threading.Thread(target=api.run, daemon=True)
    thread.start()
    poll(lambda: api.started, "uvicorn did not start", interval_s=0.05)
    try:
        yield Servers(viewer, api_port)
    finally:
        api.should_exit = True
        thread.join(timeout=10)
        viewer.stop()


def test_page_needs_token(servers: Servers) -> None:
    response = httpx.get(f"{servers.base}/studio/")
    assert response.status_code == 401
    assert response.json()["error"]["input"] == "token"


def test_page_with_token_is_viser(servers: Servers) -> None:
    response = httpx.get(f"{servers.base}/studio/?token={TOKEN}", headers={"Accept-Encoding": "gzip"})
    assert response.status_code == 200
    assert response.headers["content-encoding"] == "gzip"
    assert response.headers["content-type"].startswith("text/html")
    assert '<div id="root">' in response.text  # httpx decodes the gzip body
    assert response.cookies.get("calib_token") == TOKEN

    cookie = {"Cookie": f"calib_token={TOKEN}", "Accept-Encoding": "identity"}
    plain = httpx.get(f"{servers.base}/studio/", headers=cookie)
    assert plain.status_code == 200
    assert plain.headers.get("content-encoding", "identity") == "identity"
    assert plain.content == response.content


@pytest.mark.parametrize("headers", [{}, {SECRET_HEADER: "guess"}, {"Authorization": f"Bearer {TOKEN}"}])
def test_viewer_port_refuses_http_without_secret(servers: Servers, headers: dict[str, str]) -> None:
    for path in ("/", "/index.html"):
        response = httpx.get(f"http://{servers.direct}{path}", headers=headers)
        assert response.status_code == 403
        assert "/studio/" in response.text and '<div id="root">' not in response.text
    # the same request with the proxy's secret is viser's page: the secret is the only difference
    page = httpx.get(f"http://{servers.direct}/", headers={SECRET_HEADER: VIEWER_SECRET})
    assert page.status_code == 200 and '<div id="root">' in page.text


@pytest.mark.parametrize("headers", [None, {SECRET_HEADER: "guess"}, {"Cookie": f"calib_token={TOKEN}"}])
def test_viewer_port_refuses_websocket_without_secret(servers: Servers, headers: dict[str, str] | None) -> None:
    with pytest.raises(websockets.exceptions.InvalidStatus) as refused:
        connect(f"ws://{servers.direct}/", subprotocols=[SUBPROTOCOL], additional_headers=headers, open_timeout=5)
    assert refused.value.response.status_code == 403
    assert not servers.viewer.get_clients()
    with connect(f"ws://{servers.direct}/", subprotocols=[SUBPROTOCOL], additional_headers={
            SECRET_HEADER: VIEWER_SECRET}, open_timeout=5, max_size=MAX_MESSAGE_BYTES) as ws:
        assert isinstance(ws.recv(timeout=5), bytes)


def test_redirect_keeps_query(servers: Servers) -> None:
    response = httpx.get(f"{servers.base}/studio?token={TOKEN}")
    assert response.status_code in (302, 307)
    assert response.headers["location"] == f"/studio/?token={TOKEN}"


def test_missing_asset_is_404(servers: Servers) -> None:
    assert httpx.get(f"{servers.base}/studio/nope.js?token={TOKEN}").status_code == 404


@pytest.mark.parametrize("query", ["", "?token=wrong"])
def test_websocket_refused_without_token(servers: Servers, query: str) -> None:
    with pytest.raises(websockets.exceptions.InvalidStatus) as refused:
        connect(servers.ws + query, subprotocols=[SUBPROTOCOL], open_timeout=5)
    assert refused.value.response.status_code == 403


def test_websocket_from_a_foreign_page_is_refused_with_the_token(servers: Servers) -> None:
    """The cookie rides along with a cross-site websocket in some browsers: the Origin check refuses it anyway."""
    with pytest.raises(websockets.exceptions.InvalidStatus) as refused:
        connect(f"{servers.ws}?token={TOKEN}", subprotocols=[SUBPROTOCOL], open_timeout=5,
                additional_headers={"Origin": "http://evil.example"})
    assert refused.value.response.status_code == 403
    assert not servers.viewer.get_clients()


@pytest.mark.parametrize("path, auth", [
    ("/studio", {"query": True}),
    ("/studio/", {"cookie": True}),
    ("/studio/anything", {"query": True}),
])
def test_websocket_relays_viser_messages(servers: Servers, path: str, auth: dict[str, bool]) -> None:
    url = f"ws://127.0.0.1:{servers.api_port}{path}" + (f"?token={TOKEN}" if auth.get("query") else "")
    headers = {"Cookie": f"calib_token={TOKEN}"} if auth.get("cookie") else None
    with connect(url, subprotocols=[SUBPROTOCOL], additional_headers=headers, open_timeout=5,
                 max_size=MAX_MESSAGE_BYTES) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        message = ws.recv(timeout=5)
        assert isinstance(message, bytes) and message
        ws.send(CAMERA)  # viser lists a client once its first camera message arrives
        poll(servers.viewer.get_clients, "viser never saw the proxied client", interval_s=0.05)
    # closing the proxied socket disconnects the viser client
    poll(lambda: not servers.viewer.get_clients(), "viser client outlived the proxied websocket", interval_s=0.05)


def test_viewer_side_close_reaches_client(servers: Servers) -> None:
    with connect(f"{servers.ws}?token={TOKEN}", subprotocols=[SUBPROTOCOL], open_timeout=5,
                 max_size=MAX_MESSAGE_BYTES) as ws:
        ws.recv(timeout=5)
        servers.viewer._websock_server.disconnect_all_clients()  # viser's documented test hook
        with pytest.raises(websockets.exceptions.ConnectionClosed):
            while True:
                ws.recv(timeout=5)


@pytest.mark.browser
@pytest.mark.slow
def test_browser_renders_studio_through_proxy(servers: Servers, browser: Browser) -> None:
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    try:
        sockets: list[str] = []
        page.on("websocket", lambda ws: sockets.append(ws.url))
        page.goto(f"{servers.base}/studio/?token={TOKEN}")
        page.get_by_text("proxy-ok").first.wait_for(timeout=UI_WAIT_MS)
        poll(servers.viewer.get_clients, "viser never saw the browser", interval_s=0.1)
        assert f"ws://127.0.0.1:{servers.api_port}/studio" in sockets
        for _ in range(3):  # the 3D canvas has drawn a few frames
            wait_frame(page)
        page.screenshot(path=str(ARTIFACTS / "viewer_proxy.png"))
    finally:
        page.close()
