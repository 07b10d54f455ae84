"""The real studio (``calib-studio demo`` in a subprocess) driven through Debian chromium.

One studio process and one page serve the module, its tests in their order: the demo session is built from the
simulator in a temporary folder, the page is opened at the URL the CLI prints
first on stdout, and the intrinsics wizard is run end to end on the simulated
``cam_wide``: live capture with auto-capture (part of the board's wave), a manual capture, solve, accept;
the outcome is checked through the HTTP API against the simulator's truth. ``cam_front``, the
page's first camera, opens on enough data (the demo kept its views as auto-capture does).
"""

from __future__ import annotations

import io
import re
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
from PIL import Image
from playwright.sync_api import Browser, Page, expect

from backend.exports.target_pdf import board_sheet
from tests.conftest import (
    ARTIFACTS,
    UI_WAIT_MS,
    UI_WAIT_S,
    Studio,
    button,
    choose,
    close_toast,
    poll,
    steady,
    studio_page,
    wait_body,
    wait_frame,
    wait_still,
)

pytestmark = [pytest.mark.browser, pytest.mark.slow]

VIEWPORT = {"width": 1600, "height": 1000}
TALL_VIEWPORT = {"width": 1600, "height": 2000}
PANEL_LEFT_PX = 1150
"""The wizard panel floats over the right of the page; the 3D view is checked left of this."""
CAM_WIDE_TRUTH = {"fx": 520.0, "fy": 519.2, "cx": 637.6, "cy": 362.9}
"""``backend.sim.demo_rig.CAM_WIDE``: what the simulated wide camera really is."""
LIVE_VIEWS = 15
"""Views auto-capture keeps before the test stops it: part of one cycle of the board's wave (the whole cycle
reaching every coverage cell is ``tests/sim/test_board_scenes.py``'s, and a session whose views cover the image
reaching enough data is ``tests/services/test_live_capture.py``'s); rendering, detecting and previewing the 150
frames of a cycle took minutes of CI."""
LIVE_VIEWS_S = 600
"""Bound on auto-capture keeping :data:`LIVE_VIEWS` views on a loaded machine."""
VIEWS_RE = re.compile(r"(\d+) views ·")
RESULT_RE = re.compile(r"(r\d{4}) \((not accepted|accepted)\) · intrinsics[\s\S]*?"
                       r"(pinhole-radtan|fisheye-equidistant) 1280×720")


@pytest.fixture(scope="module")
def page(browser: Browser, studio: Studio) -> Iterator[Page]:
    """One page for the module's tests, in their order: opening one costs chromium about 5 s of CPU, and the GUI's
    state is the server's whichever page shows it."""
    with studio_page(browser, studio.url, VIEWPORT) as page:
        yield page


def _body(page: Page) -> str:
    return page.inner_text("body")


def _views(page: Page) -> int:
    match = VIEWS_RE.search(_body(page))
    return int(match.group(1)) if match else 0


def _wait_views(page: Page, at_least: int, timeout_s: float = UI_WAIT_S) -> int:
    return poll(lambda: (views := _views(page)) >= at_least and views,
                lambda: f"fewer than {at_least} views after {timeout_s:.0f} s:\n{_body(page)[-1500:]}", timeout_s, 0.5)


def _settled_views(page: Page, quiet_polls: int = 8) -> int:
    """The view count once it has not changed over ``quiet_polls`` polls 0.5 s apart (an auto-capture in flight
    has landed)."""
    return steady(lambda: _views(page), "the view count kept changing", quiet_polls, 0.5)


def _scroll_to_result(page: Page) -> None:
    page.get_by_text("Per-view RMS", exact=True).scroll_into_view_if_needed()
    page.get_by_text(re.compile(r"^reprojection RMS \d")).scroll_into_view_if_needed()


def _scene_view(page: Page) -> tuple[float, int]:
    """The 3D view's spread of grey levels and its number of distinct colours, from a screenshot."""
    shot = page.screenshot(path=ARTIFACTS / "studio_demo.png")
    rgb = np.asarray(Image.open(io.BytesIO(shot)).convert("RGB"))
    view = rgb[:, : int(PANEL_LEFT_PX * rgb.shape[1] / VIEWPORT["width"])]
    return float(view.std()), len(np.unique(view.reshape(-1, 3), axis=0))


def test_demo_page_renders_rig(page: Page) -> None:
    ARTIFACTS.mkdir(exist_ok=True)
    # frusta, boards and the live thumbnail arrive over the socket and render in software: wait until they show
    def scene_drawn() -> bool:
        wait_frame(page)
        spread, colours = _scene_view(page)
        return spread > 10.0 and colours > 200

    poll(scene_drawn, lambda: "the 3D view looks blank (std {:.1f} grey levels, {} colours)".format(*_scene_view(page)))

    # The demo session opens on cam_front, calibrated and accepted when the session was built from the views
    # auto-capture kept while the board was waved up to full coverage: enough data already.
    expect(page.get_by_label("Camera", exact=True)).to_have_value("cam_front")
    body = wait_body(page, re.compile(r"Enough data - full coverage")).string
    match = RESULT_RE.search(body)
    assert match and match.group(2) == "accepted", body
    used = re.search(r"(\d+) views used", body)  # the solve's views are the views step 3 counts
    assert used and f"{used.group(1)} views ·" in body, body
    page.get_by_text(re.compile(r"Enough data - full coverage")).scroll_into_view_if_needed()
    page.screenshot(path=ARTIFACTS / "studio_cam_front_enough_data.png")
    for text in ("RMS", "fx", "fy", "cx", "cy", "σ", "Projection σ (far points, mrcal's noise model): worst",
                 "Board flex: x "):
        assert text in body, f"{text!r} missing from the page"


def test_intrinsics_step_with_simulated_camera(page: Page, studio: Studio) -> None:
    # A tall page so the live image, the coverage bars and the result all fit in one screenshot.
    page.set_viewport_size(TALL_VIEWPORT)
    try:
        _run_intrinsics_wizard(page, studio)
    finally:
        page.set_viewport_size(VIEWPORT)


def _run_intrinsics_wizard(page: Page, studio: Studio) -> None:
    camera = page.get_by_label("Camera", exact=True)
    camera.click()
    page.get_by_role("option", name="cam_wide", exact=True).click()
    expect(camera).to_have_value("cam_wide")
    expect(page.get_by_text("No result yet.", exact=True)).to_be_visible()
    assert "views ·" not in _body(page), "cam_wide starts with no captures"

    # Live capture from the simulated camera; auto-capture keeps the frames that add coverage as the board is waved.
    button(page, "Start live capture").click()
    expect(button(page, "Stop")).to_be_visible()
    _wait_views(page, LIVE_VIEWS, timeout_s=LIVE_VIEWS_S)

    # Manual capture: with auto-capture off, one click keeps exactly one more frame.
    page.get_by_label("Auto-capture when it adds coverage").uncheck()
    before = _settled_views(page)  # an auto-capture already in flight lands first, however loaded the machine
    button(page, "Capture this frame").click()
    _wait_views(page, before + 1)
    after = _settled_views(page)
    assert after == before + 1, "a manual capture must keep exactly one frame"

    button(page, "Stop").click()
    expect(button(page, "Start live capture")).to_be_visible()
    captures = studio.get("/api/sessions/demo/sensors/cam_wide/captures")
    assert len(captures) == after, captures

    # Before a solve the panel says what is missing for enough data: the coverage not reached yet, and a solve.
    body = _body(page)
    assert "Not enough data yet:" in body and "solve to see the projection sigma" in body, body

    # Solve with the model picked on held-out views (auto) and inspect the result.
    choose(page, "Model", "auto")
    button(page, "Solve").click()
    expect(page.get_by_text(re.compile(r"^Solved in \d"))).to_be_visible(timeout=90_000)
    match = wait_body(page, RESULT_RE)  # the result lands just after the status line
    assert match.group(2) == "not accepted", _body(page)
    result_id = match.group(1)
    body = _body(page)
    assert re.search(r"reprojection RMS \d+\.\d+ px[\s\S]*\d+ views used", body), body
    for text in ("fx", "fy", "cx", "cy", "k1", "σ", "Verdict:", "Cross-validation (two halves):", "Model:",
                 "held-out RMS (px)", "pinhole-rational", "Corners:"):
        assert text in body, f"{text!r} missing from the result"
    # the enough-data line now judges the solve's projection sigma too (it follows the result)
    poll(lambda: "Not enough data yet:" in (text := _body(page)) and "solve to see the projection sigma" not in text,
         lambda: f"the enough-data line did not follow the result:\n{_body(page)[-1500:]}")
    summaries = studio.get("/api/sessions/demo/results?sensor=cam_wide&kind=intrinsics")
    assert [r["id"] for r in summaries] == [result_id], summaries
    _scroll_to_result(page)
    page.screenshot(path=ARTIFACTS / "studio_intrinsics.png")

    record = studio.get(f"/api/sessions/demo/results/{result_id}")
    level = record["verdict"]["level"]
    assert f"Verdict: {level}" in body, body  # the level as a word (in colour), never an emoji
    assert record["model_comparison"]["status"] == "compared", record["model_comparison"]
    print(f"cam_wide verdict {level}: {record['verdict']['reasons']}; model {record['model_comparison']['reason']}")
    # the result card's Accept (step 3 comes first; later steps have their own) first shows what the rig would do;
    # a result to check (from part of a wave the projection sigma may be above its tolerance) takes the user's tick
    assert level in ("trusted", "check"), record["verdict"]
    if level == "check":
        page.get_by_label("Confirm the check", exact=True).filter(visible=True).first.check()
    button(page, "Accept").first.click()
    expect(page.get_by_text(f"Accepting {result_id} would:", exact=False)).to_be_visible()
    button(page, "Confirm accept").first.click()
    expect(page.get_by_text(f"{result_id} (accepted)", exact=False)).to_be_visible()
    session = studio.get("/api/sessions/demo")
    assert session["accepted"].get("cam_wide/intrinsics") == result_id, session
    assert session["accepted"].get("cam_front/intrinsics"), "cam_front's accepted result must survive"

    K = np.array(record["camera"]["K"])
    got = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
    print(f"cam_wide from {after} views: rms {record['rms_px']:.3f} px, "
          + ", ".join(f"{k} {v:.2f} (truth {CAM_WIDE_TRUTH[k]})" for k, v in got.items()))
    assert record["rms_px"] < 1.0, record["rms_px"]
    assert abs(got["fx"] - CAM_WIDE_TRUTH["fx"]) < 5.0, got
    assert abs(got["fy"] - CAM_WIDE_TRUTH["fy"]) < 5.0, got
    # Which frames get kept depends on timing; each parameter is within 4 σ of the truth.
    for name in ("fx", "fy", "cx", "cy"):
        assert abs(got[name] - CAM_WIDE_TRUTH[name]) < 4.0 * record["std"][name] + 0.05, (name, got, record["std"])


def test_corrupt_upload_is_reported_by_name(page: Page, studio: Studio, stereo_chessboard: Path) -> None:
    """A truncated JPEG imported in the intrinsics step: a red notification names it, nothing is stored."""
    camera = page.get_by_label("Camera", exact=True).input_value()  # GUI state persists across pages
    captures_url = f"{studio.api}/api/sessions/demo/sensors/{camera}/captures"
    before = httpx.get(captures_url).json()
    data = (stereo_chessboard / "left01.jpg").read_bytes()
    with page.expect_file_chooser() as chooser:
        button(page, "Import an image file").click()
    chooser.value.set_files({"name": "broken_shot.jpg", "mimeType": "image/jpeg", "buffer": data[: len(data) // 2]})
    notice = page.locator(".mantine-Notification-root", has_text="Image not added")
    expect(notice).to_be_visible(timeout=UI_WAIT_MS)
    expect(notice).to_contain_text("broken_shot.jpg")
    expect(notice).to_contain_text("not a readable image")
    wait_still(notice)  # the toast has finished sliding in before the picture
    page.screenshot(path=ARTIFACTS / "studio_bad_upload.png")
    close_toast(page, "Image not added")  # the next test's clicks go where it floats
    assert httpx.get(captures_url).json() == before


def test_session_step_downloads_the_sessions_board(page: Page, studio: Studio) -> None:
    board = studio.get("/api/sessions/demo")["board"]
    sheet = board_sheet(board)
    choose(page, "Paper", "a4")  # the demo's board of 40 mm squares is larger than a4: refused, naming a paper
    button(page, "Print the target").click()
    expect(page.get_by_text("Cannot print the target")).to_be_visible()
    expect(page.get_by_text(f"print it on {sheet.layout.paper}", exact=False)).to_be_visible()
    choose(page, "Paper", "auto")
    button(page, "Print the target").click()
    with page.expect_download() as download:
        page.get_by_role("link", name=re.compile(re.escape(sheet.filename))).click()
    saved = Path(download.value.path()).read_bytes()
    assert download.value.suggested_filename == sheet.filename
    assert saved == sheet.pdf  # the sheet test_target_pdf.py measures


SPLINED_RESULT_RE = re.compile(r"(r\d{4}) \(not accepted\) · intrinsics[\s\S]*?splined-stereographic 1280×720")
SPLINED_TEXTS = ("LENSMODEL_SPLINED_STEREOGRAPHIC_order=3", "Knots (# reached by corners", "As OpenCV's pinhole-radtan",
                 "Board flex:", "Verdict:")
"""What the panel states of a splined result: mrcal's model name, the knots map, the OpenCV fit, the flex, the
verdict."""
SPLINED_SOLVE_S = 180.0
"""Bound on the splined solve of cam_wide's views (the OpenCV start, then the spline with the flex) on a loaded
machine."""


def test_splined_model_in_the_intrinsics_step(page: Page, studio: Studio) -> None:
    """cam_wide's views (kept by :func:`test_intrinsics_step_with_simulated_camera`) solved with mrcal's splined model:
    its own options replace k3's, and the result states the knots and the OpenCV fit, never the control points."""
    camera = page.get_by_label("Camera", exact=True)
    if camera.input_value() != "cam_wide":  # GUI state persists: the earlier test left it there
        choose(page, "Camera", "cam_wide")
    captures = studio.get("/api/sessions/demo/sensors/cam_wide/captures")
    assert len(captures) > LIVE_VIEWS, "the views test_intrinsics_step_with_simulated_camera keeps come first"
    earlier = {r["id"] for r in studio.get("/api/sessions/demo/results?sensor=cam_wide&kind=intrinsics")}

    knots = page.get_by_text("Spline knots (0: from the views)", exact=True)
    fov = page.get_by_text("Spline field across (°, 0: from the views)", exact=True)
    k3 = page.get_by_label("Estimate k3", exact=True)
    expect(k3).to_be_visible()
    expect(knots).to_be_hidden()
    choose(page, "Model", "splined-stereographic")
    expect(knots).to_be_visible()
    expect(fov).to_be_visible()
    expect(k3).to_be_hidden()

    button(page, "Solve").click()
    match = wait_body(page, SPLINED_RESULT_RE, SPLINED_SOLVE_S)
    result_id = match.group(1)
    assert result_id not in earlier, (result_id, earlier)
    body = poll(lambda: all(text in (body := _body(page)) for text in SPLINED_TEXTS) and body,
                lambda: f"the splined result is incomplete:\n{_body(page)[-2000:]}")
    assert "du_x[" not in body, "the panel lists the spline's control points"
    record = studio.get(f"/api/sessions/demo/results/{result_id}")
    assert record["camera"]["model"] == "splined-stereographic", record["camera"]
    knot_rows = record["splined"]["unconstrained_map"]  # the map reads as a grid only in a monospace block
    expect(page.locator("pre", has_text=knot_rows[len(knot_rows) // 2].strip())).to_be_visible()
    print(f"cam_wide splined from {len(captures)} views: {record['splined']['lensmodel']}, rms "
          f"{record['rms_px']:.3f} px, verdict {record['verdict']['level']}")

    page.set_viewport_size(TALL_VIEWPORT)
    try:
        page.get_by_text(re.compile(r"^Knots \(# reached by corners")).scroll_into_view_if_needed()
        page.screenshot(path=ARTIFACTS / "intrinsics_splined.png")
    finally:
        page.set_viewport_size(VIEWPORT)
