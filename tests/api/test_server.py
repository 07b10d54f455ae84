"""The studio process as a user starts it: first stdout line, health, token on API and page."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest

from tests.conftest import ROOT, poll, stop_process


def _answer(url: str) -> httpx.Response | None:
    """``GET url``'s response, or None while nothing listens there yet."""
    try:
        return httpx.get(url)
    except httpx.TransportError:
        return None


@pytest.mark.slow
def test_serve_with_token_guards_api_and_studio(tmp_path: Path, free_port: Callable[[], int]) -> None:
    api_port, viewer_port = free_port(), free_port()
    process = subprocess.Popen(
        [sys.executable, "-m", "studio.cli", "serve", "--sessions", str(tmp_path), "--port", str(api_port),
         "--viewer-port", str(viewer_port), "--token", "t0ken"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        url = process.stdout.readline().strip()
        assert url == f"http://127.0.0.1:{api_port}/studio/?token=t0ken"
        base = f"http://127.0.0.1:{api_port}"
        response = poll(lambda: _answer(f"{base}/api/health"), "the server never answered")
        assert response.status_code == 401
        assert response.json()["error"]["input"] == "token"
        assert httpx.get(f"{base}/api/health", headers={"Authorization": "Bearer t0ken"}).json() == {"status": "ok"}
        assert httpx.get(f"{base}/studio/").status_code == 401
        page = httpx.get(url)
        assert page.status_code == 200 and "<html" in page.text.lower()
        # the viewer's own port answers only the proxy (its per-process secret), not any local process
        assert httpx.get(f"http://127.0.0.1:{viewer_port}/").status_code == 403
        missing = httpx.get(f"{base}/api/no-such-route", headers={"Authorization": "Bearer t0ken"})
        assert missing.status_code == 404 and missing.json()["error"]["input"] == "/api/no-such-route"
    finally:
        stop_process(process)
