"""The LiDAR-to-camera solve of the real studio (``calib-studio demo`` in a subprocess) through Debian chromium.

The demo session stores 10 image + cloud pairs of cam_front and lidar_top with the board in view, and its rig
is the simulator's truth. On step 6 the overlay opens on the mosaic of all pairs at the truth; the sliders are
then typed away from it (yaw and x), nudged from the keyboard (viser command-palette hotkeys: L is yaw minus,
Shift+J a fine yaw plus, Z undo), solved from there with the board method, and the result is accepted. The
result, the sliders and the acceptance are checked against the truth through the HTTP API, and the overlays
(off the truth, solved) and the solve's before/after images are left in ``tests/artifacts`` to look at.
"""

from __future__ import annotations

import re
import time

import cv2
import numpy as np
import pytest
from conftest import (
    ARTIFACTS,
    Studio,
    button,
    choose,
    decoded_image,
    labelled_image,
    studio_page,
    text_input,
    wait_body,
)
from playwright.sync_api import Browser, Locator, Page, expect

from backend.core.transforms import from_xyz_ypr, invert
from backend.sim.demo_rig import demo_rig

pytestmark = [pytest.mark.browser, pytest.mark.slow]

VIEWPORT = {"width": 1600, "height": 2400}
STEP = "6 · LiDAR to camera"
CAMERA, LIDAR = "cam_front", "lidar_top"
SLOT = f"{LIDAR}/T_{CAMERA}_{LIDAR}"
SLIDERS = ("x (m)", "y (m)", "z (m)", "yaw (°)", "pitch (°)", "roll (°)")
DRAWN_RE = re.compile(r"([\d,]+) of ([\d,]+) points drawn over (\d+) pairs")
RESULT_RE = re.compile(r"(r\d{4}) \(not accepted\) · target · ✅ converged · [\d.]+ s\s+"
                       r"1σ translation \(mm\): ([\d.]+), ([\d.]+), ([\d.]+) · rotation \(°\): ([\d.]+), ([\d.]+), "
                       r"([\d.]+)")
YAW_OFF_DEG, X_OFF_M = 3.0, 0.05
"""How far the sliders are typed away from the truth before solving."""
TOLERANCE_M, TOLERANCE_DEG = 0.015, 0.3


def _wait_new_source(image: Locator, old_source: str | None, what: str, timeout_s: float = 20.0) -> str:
    """Wait until ``image`` shows a new picture (viser swaps the blob URL on every update); the new source."""
    deadline = time.monotonic() + timeout_s
    while (source := image.get_attribute("src")) == old_source:
        assert time.monotonic() < deadline, f"the overlay did not change after {what}"
        time.sleep(0.2)
    return source


def _slider_values(page: Page) -> list[float]:
    return [float(text_input(page, name).input_value()) for name in SLIDERS]


def _slider_T(page: Page) -> np.ndarray:
    """``T_camera_lidar`` as the six slider boxes show it."""
    values = _slider_values(page)
    return from_xyz_ypr(np.array(values[:3]), np.radians(values[3:]))


def _wait_yaw(page: Page, expected: float, what: str, timeout_s: float = 10.0) -> None:
    box = text_input(page, "yaw (°)")
    deadline = time.monotonic() + timeout_s
    while abs(float(box.input_value()) - expected) > 0.006:  # the box shows two decimals
        assert time.monotonic() < deadline, f"after {what} yaw is {box.input_value()}°, expected {expected:.2f}°"
        time.sleep(0.1)


def _errors(T: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Translation (m) and rotation (deg) between two transforms."""
    delta = invert(truth) @ T
    angle = np.degrees(np.arccos(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(T[:3, 3] - truth[:3, 3])), float(angle)


def _difference(a: np.ndarray, b: np.ndarray) -> float:
    """Share of pixels that differ between two overlays of the same scenes, after a blur that forgives the
    pixel or two a JPEG and a sub-degree error move the points by."""
    blur = [cv2.GaussianBlur(image, (0, 0), 2.0).astype(np.int16) for image in (a, b)]
    return float((np.abs(blur[0] - blur[1]).max(axis=2) > 12).mean())


def _focus_outside_inputs(page: Page) -> None:
    """Give the page (not a text box) the keyboard: viser ignores command hotkeys typed into an input."""
    page.get_by_text(re.compile(r"^Capture image \+ cloud pairs")).click()  # the step's help text
    assert page.evaluate("document.activeElement.tagName") == "BODY"


def _press(page: Page, key: str, yaw_expected: float, overlay: Locator) -> None:
    source = overlay.get_attribute("src")
    page.keyboard.press(key)
    _wait_yaw(page, yaw_expected, f"pressing {key}")
    _wait_new_source(overlay, source, f"pressing {key}")


def _open_step(page: Page) -> None:
    """Unfold step 6; a click that lands while the page is still laying out the panel is tried again."""
    camera = page.get_by_label("Onto camera", exact=True)
    for _ in range(3):
        page.get_by_text(STEP, exact=True).click()
        try:
            expect(camera).to_be_visible(timeout=10_000)
            return
        except AssertionError:
            continue
    expect(camera).to_be_visible()


def test_solve_from_the_sliders(browser: Browser, studio: Studio) -> None:
    truth = demo_rig().T_a_b(CAMERA, LIDAR)
    ARTIFACTS.mkdir(exist_ok=True)
    with studio_page(browser, studio.url, VIEWPORT) as page:
        for folder in ("1 · Session", "3 · Camera intrinsics"):  # fold these away: room for step 6
            page.get_by_text(folder, exact=True).click()
        _open_step(page)
        choose(page, "Onto camera", CAMERA)
        choose(page, "From LiDAR", LIDAR)

        # 1. The mosaic of all pairs, drawn at the rig's (true) transform.
        expect(page.get_by_label("Scene", exact=True)).to_have_value("all pairs")
        expect(page.get_by_text("10 pair(s) stored · showing 6", exact=True)).to_be_visible()
        drawn = wait_body(page, DRAWN_RE, timeout_s=30)
        assert int(drawn.group(3)) == 6, drawn.group(0)
        assert int(drawn.group(1).replace(",", "")) > 1000, drawn.group(0)
        assert np.allclose(_slider_T(page), truth, atol=2e-3), "the sliders do not start at the rig's transform"
        overlay = labelled_image(page, "Overlay")
        time.sleep(1)  # the last redraw of the selection lands
        at_truth = decoded_image(overlay)
        assert at_truth.shape[1] == 960 and at_truth.shape[0] > 540, f"not a mosaic: {at_truth.shape}"

        # 2. Typed away from the truth: the overlay is redrawn.
        source = overlay.get_attribute("src")
        yaw_box, x_box = text_input(page, "yaw (°)"), text_input(page, "x (m)")
        yaw_off = round(float(yaw_box.input_value()) + YAW_OFF_DEG, 2)
        yaw_box.fill(str(yaw_off))
        yaw_box.press("Enter")
        x_box.fill(str(round(float(x_box.input_value()) + X_OFF_M, 3)))
        x_box.press("Enter")
        _wait_yaw(page, yaw_off, "typing the yaw")
        source = _wait_new_source(overlay, source, "the sliders were typed away from the truth")

        # 3. Keyboard nudges (viser command hotkeys, delivered while no input has the focus).
        _focus_outside_inputs(page)
        _press(page, "l", yaw_off - 0.5, overlay)  # L: yaw minus, coarse step (0.5°)
        _press(page, "Shift+J", yaw_off - 0.45, overlay)  # Shift+J: yaw plus, fine step (0.05°)
        _press(page, "z", yaw_off - 0.5, overlay)  # Z: undo the fine step
        time.sleep(1)
        off = decoded_image(overlay)
        T_off = _slider_T(page)
        off_m, off_deg = _errors(T_off, truth)
        assert off_m > 0.04 and off_deg > 2.0, (off_m, off_deg)
        cv2.imwrite(str(ARTIFACTS / "studio_lidar_camera_solve_overlay_off.png"), off)
        page.get_by_text("Overlay", exact=True).scroll_into_view_if_needed()
        page.screenshot(path=ARTIFACTS / "studio_lidar_camera_solve_off.png")

        # 4. Solve from there (board method): converged, with sigmas, the sliders back at the truth.
        expect(page.get_by_label("Method", exact=True)).to_have_value("target (board)")
        started = time.monotonic()
        button(page, "Solve from the sliders").click()
        result = wait_body(page, RESULT_RE, timeout_s=120)
        solve_s = time.monotonic() - started
        result_id = result.group(1)
        sigmas_mm, sigmas_deg = [float(v) for v in result.group(2, 3, 4)], [float(v) for v in result.group(5, 6, 7)]
        assert all(0 < s < 15 for s in sigmas_mm) and all(0 < s < 0.5 for s in sigmas_deg), result.group(0)
        expect(page.get_by_label("Result", exact=True).last).to_have_value(result_id)
        record = studio.get(f"/api/sessions/demo/results/{result_id}")
        assert record["kind"] == "lidar_camera" and record["method"] == "target" and record["converged"]
        assert record["camera"] == CAMERA and record["sensor"] == LIDAR
        init_m, init_deg = _errors(np.array(record["T_init"]), T_off)  # the boxes round to 1 mm and 0.01°
        assert init_m < 1e-3 and init_deg < 0.02, f"the solve did not start from the sliders ({init_m}, {init_deg})"
        T_solved = np.array(record["T_camera_lidar"])
        solved_m, solved_deg = _errors(T_solved, truth)
        assert solved_m < TOLERANCE_M and solved_deg < TOLERANCE_DEG, (solved_m, solved_deg)
        deadline = time.monotonic() + 10
        while max(np.array(_errors(_slider_T(page), T_solved)) / (1e-3, 0.02)) > 1:
            assert time.monotonic() < deadline, f"the sliders show {_slider_values(page)}, not the result"
            time.sleep(0.2)
        sliders_m, sliders_deg = _errors(_slider_T(page), truth)
        assert sliders_m < TOLERANCE_M and sliders_deg < TOLERANCE_DEG, (sliders_m, sliders_deg)
        assert any(r["id"] == result_id for r in studio.get("/api/sessions/demo/results"))

        source = _wait_new_source(overlay, source, "the solve moved the sliders")
        time.sleep(1)
        solved = decoded_image(overlay)
        cv2.imwrite(str(ARTIFACTS / "studio_lidar_camera_solve_overlay_solved.png"), solved)
        near, far = _difference(solved, at_truth), _difference(off, at_truth)
        print(f"solve {result_id} in {solve_s:.1f} s: {solved_m * 1000:.1f} mm / {solved_deg:.3f}° from the truth "
              f"(started {off_m * 1000:.0f} mm / {off_deg:.2f}° off); 1σ {sigmas_mm} mm, {sigmas_deg}°; "
              f"overlay differs from the truth's in {near:.2%} of pixels solved, {far:.2%} off; {drawn.group(0)}")
        assert near < far / 3, f"the solved overlay is not back at the truth's ({near:.2%} vs {far:.2%} off)"

        page.get_by_text("Before / after", exact=True).click()
        for label in ("Before", "After"):
            image = labelled_image(page, label)
            expect(image).to_be_visible()
            picture = decoded_image(image)
            assert picture.shape[1] > 400, f"the {label} image is still the placeholder: {picture.shape}"
            cv2.imwrite(str(ARTIFACTS / f"studio_lidar_camera_solve_{label.lower()}.png"), picture)
        page.get_by_text("Before / after", exact=True).scroll_into_view_if_needed()
        page.screenshot(path=ARTIFACTS / "studio_lidar_camera_solve.png")

        # 5. Accept, sliders untouched since the solve: the solve itself is the mounting, not a manual copy.
        button(page, "Accept as the mounting").click()
        wait_body(page, re.compile(f"{result_id}: {LIDAR} is now mounted so that T_{CAMERA}_{LIDAR} is the "
                                   r"result's transform \(target solve\)"), timeout_s=15)
        wait_body(page, re.compile(f"{result_id} \\(✅ accepted\\) · target"), timeout_s=10)
        page.get_by_text("Overlay", exact=True).scroll_into_view_if_needed()
        page.screenshot(path=ARTIFACTS / "studio_lidar_camera_solve_accepted.png")
    session = studio.get("/api/sessions/demo")
    assert session["accepted"][SLOT] == result_id, session["accepted"]
    kinds = [r for r in studio.get("/api/sessions/demo/results") if r["kind"] == "lidar_camera"]
    assert [r["id"] for r in kinds] == [result_id], f"a manual result was stored beside the solve: {kinds}"
