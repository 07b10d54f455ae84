"""The LiDAR-to-camera step of the real studio (``calib-studio demo`` in a subprocess) through Debian chromium:
a captured lidar_front cloud drawn onto cam_front's image in depth colours spread over the scene (the legend
beneath), then an increment slider moved (8° about the camera's z), the overlay redrawn, and the hand-set transform
kept as a result and accepted on the result card once its 'check' verdict is confirmed."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest
from playwright.sync_api import Browser, expect

from backend.sim.demo_rig import measured_demo_rig
from tests.conftest import (
    ARTIFACTS,
    Studio,
    button,
    choose,
    decoded_image,
    labelled_image,
    studio_page,
    text_input,
    unfold,
    wait_body,
    wait_new_source,
    wait_settled,
)

pytestmark = [pytest.mark.browser, pytest.mark.slow]

VIEWPORT = {"width": 1600, "height": 2000}
DRAWN_RE = re.compile(r"([\d,]+) of ([\d,]+) points drawn")


def _coloured_pixels(png: bytes) -> int:
    """Pixels of strong colour (the TURBO-coloured points; the simulated camera's image is grey)."""
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    return int(((hsv[..., 1] > 120) & (hsv[..., 2] > 80)).sum())


def _hues(image: np.ndarray) -> int:
    """How many of 12 hue bins (30° each) hold at least 2 % of the strongly coloured pixels of a BGR image."""
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    hue = hsv[..., 0][(hsv[..., 1] > 120) & (hsv[..., 2] > 80)]
    counts = np.bincount(hue // 15, minlength=12)
    return int((counts > 0.02 * max(len(hue), 1)).sum())


def _tick(page, label: str, on: bool) -> None:
    """Set the checkbox ``label``; clicked through the DOM, since on a loaded machine the folder's opening animation
    can cover it for longer than a pointer click waits."""
    box = page.get_by_label(label, exact=True)
    expect(box).to_be_visible()
    if box.is_checked() != on:
        box.evaluate("e => e.click()")
    expect(box).to_be_checked(checked=on)


def test_overlay_follows_the_sliders(browser: Browser, studio: Studio) -> None:
    with studio_page(browser, studio.url, VIEWPORT) as page:
        unfold(page, "4 · LiDARs", button(page, "Start live"))
        for name, live in (("lidar_top", False), ("scanner_2d", False), ("sweep_3d", False), ("lidar_front", True)):
            _tick(page, name, live)
        button(page, "Start live").click()
        wait_body(page, re.compile(r"lidar_front\s+[\d.]+ Hz, [\d,]+ pts drawn"))
        button(page, "Capture clouds").click()
        wait_body(page, re.compile(r"lidar_front: 1"))
        button(page, "Stop live").click()
        page.get_by_text("4 · LiDARs", exact=True).click()  # fold it away

        unfold(page, "6 · LiDAR to camera", page.get_by_label("Onto camera", exact=True))
        expect(page.get_by_label("Onto camera", exact=True)).to_have_value("cam_front")  # the first camera
        choose(page, "From LiDAR", "lidar_front")
        first = wait_body(page, DRAWN_RE)
        overlay = labelled_image(page, "Overlay")
        wait_settled(overlay)
        overlay.scroll_into_view_if_needed()
        source_before = overlay.get_attribute("src")
        coloured = _coloured_pixels(overlay.screenshot())
        assert coloured > 500, f"the overlay shows {coloured} coloured pixels: no LiDAR points drawn"
        shown = decoded_image(overlay)
        hues = _hues(shown[:-40])
        assert hues >= 4, f"depth colours cover {hues} of 12 hue bins: the scene is painted in one colour"
        assert _hues(shown[-40:]) >= 6, "no colour bar beneath the overlay"
        legend = wait_body(page, re.compile(r"colours: depth \(m\) ([\d.]+)–([\d.]+)"))
        assert 0.5 <= float(legend.group(1)) < float(legend.group(2)) <= 40, legend.group(0)
        # The read-only pose beside the sliders.
        wait_body(page, re.compile(r"x \(m\)\s+y \(m\)\s+z \(m\)\s+yaw \(°\)\s+pitch \(°\)\s+roll \(°\)"))

        turn = text_input(page, "Δ about z (°)")  # about the camera's z (the parent's axes, the default)
        turn.fill("8")
        turn.press("Enter")
        wait_new_source(overlay, source_before, "the yaw slider moved")
        page.get_by_text("Overlay", exact=True).scroll_into_view_if_needed()
        wait_settled(overlay)
        ARTIFACTS.mkdir(exist_ok=True)
        page.screenshot(path=ARTIFACTS / "studio_lidar_camera.png")
        second = wait_body(page, DRAWN_RE)
        print(f"overlay: {first.group(0)} -> {second.group(0)}; {coloured} coloured px before the nudge")
        expect_line = "--frame-id cam_front --child-frame-id lidar_front"
        assert expect_line in page.inner_text("body")

        wait_body(page, re.compile(r"From where it was put: turned 8\.000°"))
        button(page, "Keep the sliders' transform").click()
        kept = wait_body(page, re.compile(r"(r\d{4}) \(not accepted\) · lidar_camera · manual"))
        wait_body(page, re.compile(r"set by hand: no uncertainty, no cross-check"))
        button(page, "Accept").filter(visible=True).last.click()  # the rig preview first
        wait_body(page, re.compile(f"Accepting {kept.group(1)} would:"))
        page.get_by_label("Confirm the check", exact=True).filter(visible=True).last.check()  # hand-set: "check"
        button(page, "Confirm accept").filter(visible=True).last.click()
        wait_body(page, re.compile(f"{kept.group(1)} \\(accepted\\) · lidar_camera · manual"))
    result_id = studio.get("/api/sessions/demo")["accepted"]["lidar_front/T_cam_front_lidar_front"]
    assert result_id == kept.group(1)
    record = studio.get(f"/api/sessions/demo/results/{result_id}")
    nudged = np.array(record["T_parent_child"])
    as_measured = measured_demo_rig().T_a_b("cam_front", "lidar_front")  # where the sliders started: the rig's
    angle_deg = np.degrees(np.arccos(np.clip((np.trace(as_measured[:3, :3].T @ nudged[:3, :3]) - 1) / 2, -1, 1)))
    assert record["method"] == "manual" and angle_deg == pytest.approx(8.0, abs=0.1)
