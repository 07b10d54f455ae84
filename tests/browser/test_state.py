"""Studio state that cannot wedge (issue 12, item 10), in the real studio driven through Debian chromium.

One studio process and one page serve the module: a failed live capture gives its Start
button back (every time, also after a session switch and a reload), opening a session after
the LiDAR-to-LiDAR step has drawn its clouds logs no error and reaches every later step, and
a new empty session shows nothing of the previous one in any step.
"""

from __future__ import annotations

import io
import re

import httpx
import numpy as np
import pytest
from playwright.sync_api import Browser, Page, expect

from tests.conftest import (
    ARTIFACTS,
    UI_WAIT_MS,
    Studio,
    button,
    choose,
    decoded_image,
    dismiss_webgl_warning,
    labelled_image,
    studio_page,
    text_input,
    unfold,
    wait_frame,
)

pytestmark = [pytest.mark.browser, pytest.mark.slow]

VIEWPORT = {"width": 1600, "height": 2000}
BOARD = "checkerboard:9x6:0.025"
MISSING_CAMERA = "/dev/video_h5_missing"
"""A UVC device path that does not exist (the camera is added as not connected): live capture from it fails as it
opens."""
FAILED_STARTS = 6
"""Failed starts in a row: the failure is reported by the capture thread, racing the click that started it."""
PREVIEW_GREY = 40
"""The live preview's blank frame (no capture of this camera yet)."""
RESULT_RE = re.compile(r"r\d{4} \((not accepted|accepted)\) · intrinsics[\s\S]*?"
                       r"(pinhole-radtan|fisheye-equidistant)")


def _post(studio: Studio, path: str, **kwargs) -> dict:
    response = httpx.post(f"{studio.api}{path}", timeout=30, **kwargs)
    assert response.status_code == 201, f"POST {path}: {response.status_code} {response.text}"
    return response.json()


def _cloud_npy(seed: int) -> bytes:
    """A small room-like cloud (N x 3 float32, m) as .npy bytes."""
    rng = np.random.default_rng(seed)
    points = rng.uniform([-4.0, -4.0, -0.5], [4.0, 4.0, 2.5], (4000, 3)).astype(np.float32)
    points[:1000, 2] = -0.5  # a floor, so the clouds have structure
    buffer = io.BytesIO()
    np.save(buffer, points)
    return buffer.getvalue()


def _open_session(page: Page, name: str) -> None:
    choose(page, "Session", name)
    button(page, "Open session").click()
    expect(page.get_by_text(re.compile(f"^{re.escape(name)}\\s*$")).first).to_be_visible()


def _live_buttons(page: Page) -> tuple[bool, bool]:
    return button(page, "Start live capture").is_visible(), button(page, "Stop").is_visible()


def _expect_start_only(page: Page, when: str) -> None:
    """Start shows and Stop does not, and it stays so (a late update from the capture thread would flip it)."""
    expect(button(page, "Start live capture")).to_be_visible(timeout=UI_WAIT_MS)
    expect(button(page, "Stop")).to_be_hidden(timeout=UI_WAIT_MS)
    assert _live_buttons(page) == (True, False), f"{when}: (Start, Stop) visible = {_live_buttons(page)}"


def _body(page: Page) -> str:
    return page.inner_text("body")


def test_studio_state_cannot_wedge(browser: Browser, studio: Studio) -> None:
    # A session whose only camera cannot be opened, and a second LiDAR cloud in the demo, so that the
    # LiDAR-to-LiDAR step draws a source and a target cloud.
    _post(studio, "/api/sessions", json={"name": "wedge", "board": BOARD})
    _post(studio, "/api/sessions/wedge/sensors", json={"name": "cam_gone", "kind": "camera", "connected": False,
                                                       "device": {"driver": "uvc", "device": MISSING_CAMERA}})
    _post(studio, "/api/sessions/demo/sensors/lidar_front/clouds",
          files=[("files", ("front.npy", _cloud_npy(0), "application/octet-stream"))])

    with studio_page(browser, studio.url, VIEWPORT) as page:
        # -- opening sessions after the LiDAR-to-LiDAR step drew its clouds ---------------------------------
        _open_session(page, "demo")  # draws the pair's clouds (lidar_front onto lidar_top) and lists "wedge"
        _open_session(page, "wedge")  # (the log is checked at the end; the later steps are checked on "blank")
        expect(page.get_by_label("Camera", exact=True)).to_have_value("cam_gone")

        # -- a failed live capture gives its buttons back, every time --------------------------------------
        failure = page.locator(".mantine-Notification-root", has_text="could not open camera")
        for attempt in range(FAILED_STARTS):
            button(page, "Start live capture").click()
            expect(failure.first).to_be_visible(timeout=UI_WAIT_MS)
            _expect_start_only(page, f"failed start {attempt + 1}")
            failure.first.locator("button").first.click()  # close it, so the next failure shows a new one
            expect(failure).to_have_count(0, timeout=UI_WAIT_MS)
        page.screenshot(path=ARTIFACTS / "studio_state_failed_live.png")

        # ... and after a session switch the live capture of a working camera starts and stops
        _open_session(page, "demo")
        expect(page.get_by_label("Camera", exact=True)).to_have_value("cam_front")
        _expect_start_only(page, "after the switch to demo")
        button(page, "Start live capture").click()
        expect(button(page, "Stop")).to_be_visible(timeout=UI_WAIT_MS)
        expect(button(page, "Start live capture")).to_be_hidden()
        button(page, "Stop").click()
        _expect_start_only(page, "after Stop")

        # The demo's cam_front shows its last capture, views and accepted result...
        body = _body(page)
        assert re.search(r"\d+ views ·", body) and RESULT_RE.search(body), body
        assert decoded_image(labelled_image(page, "Live")).std() > 10, "the demo's preview shows its last capture"

        # -- a new empty session shows nothing of the previous one ------------------------------------------
        name = text_input(page, "New name")
        name.fill("blank")
        name.press("Enter")
        button(page, "Create session").click()
        expect(page.get_by_text(re.compile(r"^blank\s*$")).first).to_be_visible()
        expect(text_input(page, "New name")).to_have_value("")  # the name is taken now
        page.reload()  # the page shows the server's state: the buttons too
        expect(page.get_by_text("Connected", exact=True)).to_be_visible()
        dismiss_webgl_warning(page)
        for folder, inside in (("4 · LiDARs", "Source LiDAR"), ("6 · LiDAR to camera", "Onto camera"),
                               ("7 · Multi-camera", "Reference camera")):
            unfold(page, folder, page.get_by_label(inside, exact=True))
        _check_blank(page)
        _expect_start_only(page, "in the new session, after a reload")
        page.get_by_text("3 · Camera intrinsics", exact=True).scroll_into_view_if_needed()
        wait_frame(page)
        page.screenshot(path=ARTIFACTS / "studio_state_new_session.png")

    log = studio.log.read_text(errors="replace")
    for bad in ("Traceback", "RuntimeError", "already removed"):
        assert bad not in log, f"{bad!r} in the studio's log:\n{studio.log_tail(60)}"


def _check_blank(page: Page) -> None:
    """Every step shows the empty session "blank", nothing of the demo."""
    expect(page.get_by_label("Session", exact=True)).to_have_value("blank")
    expect(page.get_by_label("Camera", exact=True)).to_have_value("(no camera)")
    expect(page.get_by_text("No result yet.", exact=True)).to_be_visible()
    expect(page.get_by_label("History", exact=True)).to_have_value("(none)")
    body = _body(page)
    assert not re.search(r"\d+ views ·", body) and "No views yet." in body, body
    assert not RESULT_RE.search(body), f"a previous result is on show:\n{body}"
    preview = decoded_image(labelled_image(page, "Live"))
    assert np.abs(preview.astype(int) - PREVIEW_GREY).max() <= 3, "the preview still shows the previous camera image"
    for text in ("No LiDAR in this session", "No LiDAR-to-LiDAR result yet.", "Not live.",
                 "Pick a camera and a LiDAR", "No LiDAR-to-camera result yet.", "Nothing to draw yet.",
                 "Tick at least two cameras.", "No multi-camera result for these cameras yet."):
        assert text in body, f"{text!r} missing:\n{body}"
    for label in ("Source LiDAR", "Target LiDAR"):
        expect(page.get_by_label(label, exact=True)).to_have_value("(no LiDAR)")
    for label in ("Onto camera", "From LiDAR", "Reference camera"):
        expect(page.get_by_label(label, exact=True)).to_have_value("(none)")
    for label in ("demo", "cam_front", "lidar_top", "fitness"):
        assert label not in body.split("Create session", 1)[1], f"{label!r} of the demo still shows:\n{body}"
