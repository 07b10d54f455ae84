"""Who may drive the server: Host and Origin checks (CSRF, DNS rebinding) on the API and the viewer, with and
without a token, and the offline API docs."""

from __future__ import annotations

import re
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest
import viser
import websockets.asyncio.server
import websockets.exceptions
from fastapi.testclient import TestClient
from playwright.sync_api import Browser, Route, expect
from starlette.websockets import WebSocketDisconnect
from websockets.sync.client import connect

from backend.api.app import create_app
from backend.api.origin import OriginPolicy
from backend.api.viewer_guard import origin_check, start_viewer
from backend.api.viewer_proxy import mount_viewer_proxy
from tests.conftest import ARTIFACTS, ROOT, stop_process, wait_health

API, VIEWER = 8000, 8080
BASE = f"http://127.0.0.1:{API}"
EVIL = "http://evil.example"
BOARD = "checkerboard:9x6:0.025"
SUBPROTOCOL = "viser-v" + viser.__version__


def assert_refused(response: httpx.Response, header: str) -> None:
    assert response.status_code == 403, response.text
    error = response.json()["error"]
    assert set(error) == {"message", "input"} and error["input"] == header
    assert header in error["message"]


def upload(client: TestClient, image: bytes, **headers: str) -> httpx.Response:
    return client.post("/api/sessions/s/sensors/cam/captures", files=[("files", ("left01.jpg", image, "image/jpeg"))],
                       headers=headers)


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    """The API as served on 127.0.0.1:8000 beside a viewer on 8080, with session ``s`` holding camera ``cam``."""
    app = create_app(tmp_path, origins=OriginPolicy.for_server("127.0.0.1", (API, VIEWER)))
    with TestClient(app, base_url=BASE) as c:
        assert c.post("/api/sessions", json={"name": "s", "board": BOARD}).status_code == 201
        assert c.post("/api/sessions/s/sensors", json={"name": "cam"}).status_code == 201
        yield c
    app.state.studio.jobs.shutdown()


@pytest.fixture(scope="module")
def image(left_images: list[Path]) -> bytes:
    return left_images[0].read_bytes()


@pytest.mark.parametrize("origin", [EVIL, f"{EVIL}:{API}", "null", f"http://127.0.0.1:{API + 1}",
                                    f"http://127.0.0.1.evil.example:{API}", f"ftp://127.0.0.1:{API}"])
def test_cross_origin_upload_is_refused_and_stores_nothing(client: TestClient, image: bytes, origin: str) -> None:
    assert_refused(upload(client, image, Origin=origin), "Origin")
    assert client.get("/api/sessions/s/sensors/cam/captures").json() == []
    assert_refused(client.post("/api/sessions", json={"name": "t"}, headers={"Origin": origin}), "Origin")
    assert_refused(client.put("/api/sessions/s/board", json={"board": BOARD}, headers={"Origin": origin}), "Origin")
    assert [s["name"] for s in client.get("/api/sessions").json()] == ["s"]


@pytest.mark.parametrize("origin", [f"http://127.0.0.1:{VIEWER}", f"http://localhost:{VIEWER}", BASE,
                                    f"http://[::1]:{API}", None])
def test_own_origins_and_no_origin_pass(client: TestClient, image: bytes, origin: str | None) -> None:
    response = upload(client, image, **({"Origin": origin} if origin else {}))
    assert response.status_code == 201, response.text
    assert len(client.get("/api/sessions/s/sensors/cam/captures").json()) == 1


def test_reading_from_a_foreign_page_is_not_refused(client: TestClient) -> None:
    """A GET changes nothing; the browser keeps a foreign page from reading the answer (no CORS headers)."""
    response = client.get("/api/sessions", headers={"Origin": EVIL})
    assert response.status_code == 200 and "access-control-allow-origin" not in response.headers


@pytest.mark.parametrize("host", ["evil.example", f"evil.example:{API}", f"127.0.0.1:{API + 1}", "127.0.0.1",
                                  f"127.0.0.2:{API}", f"user@127.0.0.1:{API}", "127.0.0.1:port", ""])
def test_foreign_host_is_refused_on_every_method(client: TestClient, image: bytes, host: str) -> None:
    assert_refused(client.get("/api/health", headers={"Host": host}), "Host")
    assert_refused(client.get("/docs", headers={"Host": host}), "Host")
    assert_refused(upload(client, image, Host=host), "Host")
    assert client.get("/api/sessions/s/sensors/cam/captures").json() == []


@pytest.mark.parametrize("host", [f"localhost:{API}", f"LOCALHOST:{API}", f"[::1]:{API}", f"127.0.0.1:{VIEWER}"])
def test_loopback_names_with_our_ports_pass(client: TestClient, host: str) -> None:
    assert client.get("/api/health", headers={"Host": host}).json() == {"status": "ok"}


def test_bound_address_and_wildcard_bind() -> None:
    lan = OriginPolicy.for_server("192.168.7.20", (API, VIEWER))
    assert lan.authority_ok(f"192.168.7.20:{API}") and lan.origin_ok(f"http://192.168.7.20:{VIEWER}")
    assert not lan.authority_ok(f"192.168.7.21:{API}") and not lan.authority_ok("192.168.7.20")
    everywhere = OriginPolicy.for_server("0.0.0.0", (API,))
    assert everywhere.authority_ok(f"10.1.2.3:{API}") and everywhere.authority_ok(f"[fe80::1]:{API}")
    assert not everywhere.authority_ok(f"evil.example:{API}") and not everywhere.authority_ok("10.1.2.3:1")


def test_checks_hold_in_token_mode_before_the_token(tmp_path: Path, image: bytes) -> None:
    app = create_app(tmp_path, token="t0ken", origins=OriginPolicy.for_server("127.0.0.1", (API,)))
    bearer = {"Authorization": "Bearer t0ken"}
    with TestClient(app, base_url=BASE) as c:
        assert c.post("/api/sessions", json={"name": "s", "board": BOARD}, headers=bearer).status_code == 201
        assert_refused(c.post("/api/sessions", json={"name": "t"}, headers=bearer | {"Origin": EVIL}), "Origin")
        assert_refused(c.get("/api/health", headers=bearer | {"Host": "evil.example"}), "Host")
        assert_refused(c.get("/api/health", headers={"Host": "evil.example"}), "Host")  # 403 before the 401
        assert [s["name"] for s in c.get("/api/sessions", headers=bearer).json()] == ["s"]
    app.state.studio.jobs.shutdown()


def test_without_a_policy_origin_must_be_the_host(tmp_path: Path) -> None:
    """The in-process app (no address of its own) still refuses a state change from a foreign page."""
    app = create_app(tmp_path)
    with TestClient(app) as c:  # Host: testserver
        assert_refused(c.post("/api/sessions", json={"name": "t"}, headers={"Origin": EVIL}), "Origin")
        assert c.post("/api/sessions", json={"name": "t"}, headers={"Origin": "http://testserver"}).status_code == 201
        assert c.get("/api/health", headers={"Host": "anything"}).status_code == 200
    app.state.studio.jobs.shutdown()


def test_studio_websocket_from_a_foreign_page_is_refused(tmp_path: Path) -> None:
    app = create_app(tmp_path, token="t0ken", origins=OriginPolicy.for_server("127.0.0.1", (API,)))
    mount_viewer_proxy(app, 1, "t0ken", "secret")  # no viewer behind it: the guard answers first
    with TestClient(app, base_url=BASE) as c:
        for headers in ({"Origin": EVIL}, {"Host": "evil.example"}):
            with pytest.raises(WebSocketDisconnect) as refused:
                with c.websocket_connect("/studio?token=t0ken", headers=headers):
                    pass
            assert refused.value.code == 1008
    app.state.studio.jobs.shutdown()


@pytest.fixture(scope="module")
def guarded_viewer(free_port: Callable[[], int]) -> Iterator[viser.ViserServer]:
    """A viewer served on loopback without a token: it answers only its own pages."""
    serve = websockets.asyncio.server.serve
    viewer = start_viewer("127.0.0.1", free_port(), origin_check("127.0.0.1"))
    assert websockets.asyncio.server.serve is serve  # the check was put in front of viser's server only
    try:
        yield viewer
    finally:
        viewer.stop()


def test_viewer_without_token_refuses_foreign_pages(guarded_viewer: viser.ViserServer) -> None:
    port = guarded_viewer.get_port()
    own = f"http://127.0.0.1:{port}"
    assert '<div id="root">' in httpx.get(f"{own}/").text
    assert httpx.get(f"http://localhost:{port}/").status_code == 200
    assert httpx.get(f"{own}/", headers={"Host": f"evil.example:{port}"}).status_code == 403
    handshake = {"Upgrade": "websocket", "Connection": "Upgrade", "Sec-WebSocket-Version": "13",
                 "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ==", "Sec-WebSocket-Protocol": SUBPROTOCOL}
    assert httpx.get(f"{own}/", headers=handshake | {"Host": f"evil.example:{port}"}).status_code == 403
    assert httpx.get(f"{own}/", headers=handshake | {"Host": f"127.0.0.1:{port}"}).status_code == 101
    for headers in ({"Origin": EVIL}, {"Origin": f"http://127.0.0.1:{port + 1}"}, {"Origin": "null"}):
        with pytest.raises(websockets.exceptions.InvalidStatus) as refused:
            connect(f"ws://127.0.0.1:{port}/", subprotocols=[SUBPROTOCOL], additional_headers=headers,
                    open_timeout=5)
        assert refused.value.response.status_code == 403
    with connect(f"ws://127.0.0.1:{port}/", subprotocols=[SUBPROTOCOL], additional_headers={"Origin": own},
                 open_timeout=5) as ws:
        assert isinstance(ws.recv(timeout=5), bytes)


def test_docs_are_served_offline(client: TestClient) -> None:
    for page in ("/docs", "/redoc"):
        response = client.get(page)
        assert response.status_code == 200 and "text/html" in response.headers["content-type"]
        assert "http://" not in response.text and "https://" not in response.text and "//cdn" not in response.text
        assets = re.findall(r"""(?:src|href|spec-url|url:)\s*=?\s*['"]([^'"]+)['"]""", response.text)
        assert "/openapi.json" in assets and any(a.endswith(".js") for a in assets), assets
        for asset in assets:
            assert asset.startswith("/") and not asset.startswith("//"), asset
            fetched = client.get(asset)
            assert fetched.status_code == 200 and len(fetched.content) > 100, asset
    assert "SwaggerUIBundle" in client.get("/static-offline-docs/swagger-ui-bundle.js").text
    assert '"validatorUrl": null' in client.get("/docs").text  # Swagger UI's online validator badge is off


@dataclass
class Served:
    api: str
    viewer_port: int


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory, free_port: Callable[[], int]) -> Iterator[Served]:
    """``calib-studio serve`` on loopback without a token, on an empty sessions folder."""
    api_port, viewer_port = free_port(), free_port()
    while viewer_port == api_port:
        viewer_port = free_port()
    process = subprocess.Popen(
        [sys.executable, "-m", "studio.cli", "serve", "--sessions", str(tmp_path_factory.mktemp("served")),
         "--port", str(api_port), "--viewer-port", str(viewer_port)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert process.stdout.readline().strip() == f"http://127.0.0.1:{viewer_port}/"
        base = f"http://127.0.0.1:{api_port}"
        wait_health(base, process, lambda: "(stderr discarded)")
        yield Served(base, viewer_port)
    finally:
        stop_process(process)


@pytest.mark.slow
def test_served_process_checks_api_and_viewer(served: Served) -> None:
    """The wiring of :mod:`studio.server`: the API's and the viewer's checks with the real ports."""
    base, viewer_port = served.api, served.viewer_port
    assert_refused(httpx.post(f"{base}/api/sessions", json={"name": "x"}, headers={"Origin": EVIL}), "Origin")
    assert_refused(httpx.get(f"{base}/api/sessions", headers={"Host": f"evil.example:{viewer_port}"}), "Host")
    studio_page = {"Origin": f"http://127.0.0.1:{viewer_port}"}
    assert httpx.post(f"{base}/api/sessions", json={"name": "x"}, headers=studio_page).status_code == 201
    assert [s["name"] for s in httpx.get(f"{base}/api/sessions").json()] == ["x"]
    with pytest.raises(websockets.exceptions.InvalidStatus) as refused:
        connect(f"ws://127.0.0.1:{viewer_port}/", subprotocols=[SUBPROTOCOL], additional_headers={"Origin": EVIL},
                open_timeout=5)
    assert refused.value.response.status_code == 403
    with connect(f"ws://127.0.0.1:{viewer_port}/", subprotocols=[SUBPROTOCOL], additional_headers=studio_page,
                 open_timeout=5, max_size=50 * 1024 * 1024) as ws:
        assert isinstance(ws.recv(timeout=5), bytes)


@pytest.mark.browser
@pytest.mark.slow
def test_docs_render_with_the_network_cut_off(served: Served, browser: Browser) -> None:
    """Swagger UI draws the API's operations in chromium while every request off this server is aborted."""
    context = browser.new_context(viewport={"width": 1280, "height": 900})
    foreign: list[str] = []

    def local_only(route: Route) -> None:
        if route.request.url.startswith(served.api + "/"):
            route.continue_()
        else:
            foreign.append(route.request.url)
            route.abort()

    try:
        context.route("**/*", local_only)
        page = context.new_page()
        page.goto(f"{served.api}/docs")
        expect(page.get_by_text("Calibration Studio API").first).to_be_visible(timeout=30_000)
        expect(page.locator(".opblock-summary-path", has_text="/api/health").first).to_be_visible()
        page.screenshot(path=str(ARTIFACTS / "docs_offline.png"))
        assert foreign == []
    finally:
        context.close()
