"""The intensity-image path in the real studio (``calib-studio demo --rig servo-scanner`` in a subprocess) driven
through Debian chromium: the servo-scanner session opens, step 5's *Board corners → camera* panel lists its image +
sweep pairs by pan reading and shows a sweep's intensity image with the board's corners found, *Solve corners*
solves the camera at pan 0 as a job, and the result card shows the result with its sigma and verdict while the
sweep, coloured by the camera's image through it, is drawn in 3D; through the HTTP API the result is the corners
method's and within 1 cm and 0.3 deg of the simulator's truth. Screenshots go to :data:`SHOTS`.

The session is the run's servo-scanner template (built once from the byte-level simulators), so the studio's
build job finds it built and opens it at once.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from playwright.sync_api import Browser, expect

from backend.core.transforms import transform_error
from backend.services.demo_servo_scanner import CAMERA_NAME, LIDAR_NAME, SERVO_SCANNER_NAME
from backend.store.session import SessionStore
from tests.conftest import Studio, button, labelled_image, serving, studio_page, wait_body, wait_settled
from tests.servo_scanner_rig import servo_scanner_sessions, true_T_camera_lidar

pytestmark = [pytest.mark.browser, pytest.mark.slow]

VIEWPORT = {"width": 1600, "height": 2400}
SHOTS = Path("/tmp/servo_browser")
"""Where the screenshots go, for a person to look at."""
CORNERS_IMAGE = "The board's corners in the sweep's intensity image"
RESULT_RE = re.compile(r"(r\d{4}) \(not accepted\) · lidar_camera · corners · [\d.]+ s")


@pytest.fixture(scope="module")
def studio(tmp_path_factory: pytest.TempPathFactory, free_port: Callable[[], int]) -> Iterator[Studio]:
    sessions = servo_scanner_sessions(tmp_path_factory, "servo_scanner_browser")
    with serving(sessions, free_port, sessions.parent / "studio.log", ("demo", "--rig", "servo-scanner")) as studio:
        yield studio


def test_the_corners_solve_from_the_studio(browser: Browser, studio: Studio) -> None:
    SHOTS.mkdir(exist_ok=True)
    with studio_page(browser, studio.url, VIEWPORT) as page:
        expect(page.get_by_text(re.compile("Simulated servo-scanner rig"))).to_be_visible()
        page.get_by_text("5 · Swept scanner", exact=True).click()
        expect(page.get_by_label("Swept scanner", exact=True)).to_have_value(LIDAR_NAME)
        expect(page.get_by_label("Paired camera", exact=True)).to_have_value(CAMERA_NAME)
        expect(page.get_by_label("Pan reading", exact=True)).to_have_value("+0° (6 pairs)")
        wait_body(page, re.compile(rf"14 image \+ sweep pair\(s\) of {CAMERA_NAME} at 3 pan reading\(s\)"))
        corners_image = labelled_image(page, CORNERS_IMAGE)
        corners_image.scroll_into_view_if_needed()
        wait_settled(corners_image)
        page.screenshot(path=SHOTS / "corners_before_solve.png")

        solve = button(page, "Solve corners")
        solve.scroll_into_view_if_needed()
        solve.click()
        match = wait_body(page, RESULT_RE, timeout_s=180)  # a loaded 2-core machine: corners of six sweeps, a solve
        result_id = match.group(1)
        wait_body(page, re.compile(rf"Corners of {CAMERA_NAME} at pan \+0°: done in [\d.]+ s"))
        # the card: the transform with its 1-sigma, the verdict with its reasons; beside it the placements
        wait_body(page, re.compile(rf"{CAMERA_NAME} → {LIDAR_NAME}: .* m · rotation vector .*°\s+1σ: "
                                   r"\d+\.\d+, \d+\.\d+, \d+\.\d+ mm · \d+\.\d+, \d+\.\d+, \d+\.\d+° about x, y, z"))
        verdict = wait_body(page, re.compile(r"Verdict: (trusted|check|reject)"))
        wait_body(page, re.compile(r"cross-check the target method on the same placements"))
        wait_body(page, re.compile(r"Corners at pan \+0°"))
        coloured = wait_body(page, re.compile(rf"([\d,]+) of ([\d,]+) points of the sweep coloured by \d+'s image "
                                              rf"through {result_id}"))
        assert int(coloured.group(1).replace(",", "")) > 5000
        wait_settled(corners_image)
        page.get_by_text("Corners at pan +0°").scroll_into_view_if_needed()
        page.screenshot(path=SHOTS / "corners_result.png")
        corners_image.scroll_into_view_if_needed()
        page.screenshot(path=SHOTS / "corners_image_and_cloud.png")

    record = studio.get(f"/api/sessions/{SERVO_SCANNER_NAME}/results/{result_id}")
    assert (record["method"], record["parent"], record["child"]) == ("corners", CAMERA_NAME, LIDAR_NAME)
    assert record["verdict"]["level"] == verdict.group(1)
    session = SessionStore(Path(studio.process.args[studio.process.args.index("--sessions") + 1])).get(
        SERVO_SCANNER_NAME)
    error_m, error_deg = transform_error(np.array(record["T_parent_child"]), true_T_camera_lidar(session))
    print(f"{result_id} from the studio: {1000 * np.linalg.norm(error_m):.2f} mm, {np.linalg.norm(error_deg):.3f} deg "
          f"off the truth; verdict {record['verdict']['level']}")
    assert np.linalg.norm(error_m) < 0.01 and np.linalg.norm(error_deg) < 0.3
