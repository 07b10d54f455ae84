"""Work whose client left is stopped: an image upload being checked when its client disconnects stops at the next
image and stores nothing (a real uvicorn server on 127.0.0.1, a client that closes its socket)."""

from __future__ import annotations

import logging
import socket
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest
import uvicorn

from backend.api import client_watch
from backend.api.app import create_app
from backend.calib.intrinsics import service
from tests.conftest import poll

BOARD = "checkerboard:9x6:0.025"
IMAGES = 4


@pytest.fixture
def api(tmp_path: Path, free_port: Callable[[], int]) -> Iterator[str]:
    """The API on a free port, with session ``s`` and camera ``cam``; yields its base URL."""
    app = create_app(tmp_path)
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    poll(lambda: server.started, "uvicorn did not start", interval_s=0.05)
    base = f"http://127.0.0.1:{port}"
    assert httpx.post(f"{base}/api/sessions", json={"name": "s", "board": BOARD}).status_code == 201
    assert httpx.post(f"{base}/api/sessions/s/sensors", json={"name": "cam"}).status_code == 201
    try:
        yield base
    finally:
        server.should_exit = True
        thread.join(timeout=10)
        app.state.studio.jobs.shutdown()


def multipart(files: list[tuple[str, bytes]]) -> tuple[bytes, str]:
    boundary = "calib-test-boundary"
    parts = [f'--{boundary}\r\nContent-Disposition: form-data; name="files"; filename="{name}"\r\n'
             f"Content-Type: application/octet-stream\r\n\r\n".encode() + data + b"\r\n" for name, data in files]
    return b"".join(parts) + f"--{boundary}--\r\n".encode(), boundary


def test_an_upload_whose_client_left_stops_and_stores_nothing(api: str, left_images: list[Path], monkeypatch,
                                                              caplog: pytest.LogCaptureFixture) -> None:
    watches: list[threading.Event] = []
    monkeypatch.setattr(client_watch, "Event", lambda: watches.append(threading.Event()) or watches[-1])
    first_seen = threading.Event()
    detected: list[str] = []
    real_detect = service.detect_upload

    def detect_until_the_client_left(image, board, name):
        detected.append(name)
        first_seen.set()
        assert watches[-1].wait(30), "the server did not hear the client leave"
        return real_detect(image, board, name)

    monkeypatch.setattr(service, "detect_upload", detect_until_the_client_left)
    files = [(f"left{i}.jpg", left_images[i].read_bytes()) for i in range(IMAGES)]
    body, boundary = multipart(files)
    port = int(api.rsplit(":", 1)[1])
    caplog.set_level(logging.WARNING, logger=client_watch.__name__)
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.sendall(f"POST /api/sessions/s/sensors/cam/captures HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                     f"Content-Type: multipart/form-data; boundary={boundary}\r\n"
                     f"Content-Length: {len(body)}\r\n\r\n".encode() + body)
        assert first_seen.wait(30), "the server never started on the upload"
    # The socket is closed while the first image is being checked: the upload stops before the second.
    poll(lambda: any("the client left" in r.getMessage() for r in caplog.records),
         "the server did not stop the upload whose client left", timeout_s=30)
    assert detected == ["left0.jpg"], "images were still checked after the client left"
    message = next(r.getMessage() for r in caplog.records if "the client left" in r.getMessage())
    assert "POST /api/sessions/s/sensors/cam/captures" in message and "detecting the target in left1.jpg" in message
    assert httpx.get(f"{api}/api/sessions/s/sensors/cam/captures").json() == []
