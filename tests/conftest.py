"""Shared fixtures: paths to the real data sets in ../shared/data."""

from __future__ import annotations

import socket
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from playwright.sync_api import Browser, sync_playwright

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
STEREO_CHESSBOARD = SHARED_DATA / "opencv_stereo_chessboard"


@pytest.fixture(scope="session")
def stereo_chessboard() -> Path:
    if not STEREO_CHESSBOARD.is_dir():
        pytest.fail(f"real data missing: {STEREO_CHESSBOARD} (shared/data must sit beside the checkout)")
    return STEREO_CHESSBOARD


@pytest.fixture(scope="session")
def left_images(stereo_chessboard: Path) -> list[Path]:
    return sorted(stereo_chessboard.glob("left*.jpg"))


ARTIFACTS = Path(__file__).parent / "artifacts"
"""Screenshots the browser tests leave for a person to look at."""
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless=new", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 "--ignore-gpu-blocklist", "--disable-background-networking", "--disable-component-update",
                 "--no-first-run"]
"""Debian's chromium with software WebGL (see ../shared/stack-notes.md); Playwright cannot fetch its own."""


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture(scope="session")
def free_port() -> Callable[[], int]:
    """A function returning a free TCP port on 127.0.0.1."""
    return _free_port


@pytest.fixture(scope="session")
def browser() -> Iterator[Browser]:
    """One headless Debian chromium for the whole run, driven by Playwright."""
    ARTIFACTS.mkdir(exist_ok=True)
    with sync_playwright() as playwright:
        chromium = playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield chromium
        finally:
            chromium.close()


def stop_process(process: subprocess.Popen) -> None:
    """Ask a server process to stop, and kill it if it has not within 15 s."""
    process.terminate()
    try:
        process.wait(timeout=15)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(timeout=10)
