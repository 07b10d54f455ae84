"""``calib-studio demo`` on a fresh sessions folder: the page serves at once while the demo session is built in
the background (the session step shows its progress), then the studio opens it; what an interrupted build left
in the staging folder is cleared, and no half-built demo is ever listed."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest
from playwright.sync_api import Browser, expect

from backend.services.demo import DEMO_NAME, DEMO_PAIRS, STAGING_DIR
from tests.conftest import ARTIFACTS, start_demo, stop_process, studio_page, wait_health

VIEWPORT = {"width": 1400, "height": 1000}

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def _names(base: str) -> list[str]:
    return [entry["name"] for entry in httpx.get(f"{base}/api/sessions", timeout=10).json()]


def test_the_page_serves_while_the_demo_is_built_then_opens_it(browser: Browser, tmp_path: Path,
                                                                free_port: Callable[[], int]) -> None:
    sessions = tmp_path / "sessions"
    leftover = sessions / STAGING_DIR / DEMO_NAME  # a build killed half-way through an earlier start
    leftover.mkdir(parents=True)
    (leftover / "session.json").write_text('{"half": ')
    log = tmp_path / "studio.log"
    process, api_port, viewer_port = start_demo(sessions, free_port, log)
    base = f"http://127.0.0.1:{api_port}"
    try:
        url = process.stdout.readline().strip()
        assert url == f"http://127.0.0.1:{viewer_port}/"  # still the first line, before the demo exists
        wait_health(base, process, lambda: log.read_text()[-2000:], timeout_s=120)
        # in a terminal stderr shows too: the URL comes first there as well, with no banner before it
        assert log.read_text().splitlines()[0] == f"API and docs: http://127.0.0.1:{api_port}/docs"
        assert DEMO_NAME not in _names(base)  # serving already; the demo is still being built
        with studio_page(browser, url, VIEWPORT) as page:
            progress = page.get_by_text(re.compile(r"Preparing the demo session … \d+ %"))
            expect(progress).to_be_visible(timeout=60_000)
            page.screenshot(path=ARTIFACTS / "demo_preparing.png")
            expect(page.get_by_text("Simulated rig (known ground truth)")).to_be_visible(timeout=900_000)
            expect(progress).to_have_count(0)
            page.screenshot(path=ARTIFACTS / "demo_opened.png")
        assert _names(base) == [DEMO_NAME]
        assert not (sessions / STAGING_DIR).exists()
        pairs = httpx.get(f"{base}/api/sessions/{DEMO_NAME}/lidar-camera/pairs",
                          params={"camera": "cam_front", "lidar": "lidar_top"}, timeout=10).json()
        assert len(pairs) == DEMO_PAIRS and all(p["board_found"] for p in pairs)
    finally:
        stop_process(process)
