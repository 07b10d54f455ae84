"""The disaster-response rig in the real studio (``calib-studio demo --rig disaster-response`` in a subprocess) through
Debian chromium: the session opens on its wall test field (its survey uploaded) and V-target; step 3 shows the
camera's test-field views with each marker centre found and the photogrammetric result accepted, and its *Pose in
the test field* resects the newest wall image (near the simulator's truth); step 6 solves the
Livox to the Blackfly by the V-target method from the 18 stored pairs, starting at the tape-measured mounting, and
the result, trusted, is checked against the simulator's truth through the API. Screenshots are left in
``tests/artifacts`` to look at."""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator

import numpy as np
import pytest
from playwright.sync_api import Browser, expect

from backend.core.transforms import invert, transform_error
from backend.services.demo_disaster_response import DISASTER_RESPONSE_NAME
from backend.sim.disaster_response import CAMERA, LIDAR, T_CAMERA_LIVOX_TRUE
from backend.sim.marker_targets import field_views
from tests.conftest import (
    ARTIFACTS,
    Studio,
    button,
    choose,
    disaster_response_template,
    fresh_demo,
    serving,
    studio_page,
    unfold,
    wait_body,
)

pytestmark = [pytest.mark.browser, pytest.mark.slow]

VIEWPORT = {"width": 1600, "height": 2400}
RESULT_RE = re.compile(r"(r\d{4}) \(not accepted\) · lidar_camera · vtarget · [\d.]+ s\s+Verdict: trusted\.")


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory, free_port: Callable[[], int]) -> Iterator[Studio]:
    """``calib-studio demo --rig disaster-response`` on a copy of the session, built once per run."""
    tmp = tmp_path_factory.mktemp("disaster_response")
    fresh_demo(disaster_response_template(tmp_path_factory), tmp / "sessions")
    with serving(tmp / "sessions", free_port, tmp / "studio.log", ("demo", "--rig", "disaster-response")) as studio:
        yield studio


def test_the_v_target_path(browser: Browser, rig: Studio) -> None:
    ARTIFACTS.mkdir(exist_ok=True)
    with studio_page(browser, rig.url, VIEWPORT) as page:
        wait_body(page, re.compile(r"Board: testfield:DICT_4X4_50:0\.15:survey\.csv \(survey uploaded\)\s+"
                                   r"V-target: vtarget:1x0\.6:120:3x2:0\.15:DICT_4X4_50"))
        page.screenshot(path=ARTIFACTS / "studio_disaster_response_session.png")
        page.get_by_text("1 · Session", exact=True).click()  # fold it away: room for the next steps

        unfold(page, "3 · Camera intrinsics", page.get_by_label("Camera", exact=True).first)
        wait_body(page, re.compile(r"r0001 \(accepted\) · intrinsics"))
        page.screenshot(path=ARTIFACTS / "studio_disaster_response_intrinsics.png")
        resect = button(page, "Resect this image")
        unfold(page, "Pose in the test field", resect)
        expect(page.get_by_label("Wall image", exact=True)).to_have_value(re.compile(r"^wall_11\.png \(\d+\)$"))
        resect.click()
        wait_body(page, re.compile(r"T_wall_camera: .* m · yaw, pitch, roll .*°\s+1σ: .* mm · .*° about x, y, z"))
        wait_body(page, re.compile(r"RMS \d\.\d{3} px over \d+ of \d+ markers\s+Verdict: (trusted|check)"))
        page.get_by_text("Pose in the test field", exact=True).scroll_into_view_if_needed()
        page.screenshot(path=ARTIFACTS / "studio_disaster_response_exterior.png")
        page.get_by_text("3 · Camera intrinsics", exact=True).click()

        unfold(page, "6 · LiDAR to camera", page.get_by_label("Onto camera", exact=True))
        choose(page, "Onto camera", CAMERA)
        choose(page, "From LiDAR", LIDAR)
        wait_body(page, re.compile(r"18 pair\(s\) stored"))
        button(page, "Reset to rig").click()
        choose(page, "Method", "V-target (two plates)")
        button(page, "Solve from the sliders").click()
        result = wait_body(page, RESULT_RE, timeout_s=180)
        page.get_by_text("Overlay", exact=True).scroll_into_view_if_needed()
        page.screenshot(path=ARTIFACTS / "studio_disaster_response_v_target.png")
        expect(page.get_by_label("Result", exact=True).last).to_have_value(result.group(1))
    posed = rig.get(f"/api/sessions/{DISASTER_RESPONSE_NAME}/sensors/{CAMERA}/exterior")[-1]
    trans_m, rot_deg = transform_error(np.array(posed["T_parent_child"]), invert(field_views()[11]))
    assert np.linalg.norm(trans_m) < 0.005 and np.linalg.norm(rot_deg) < 0.1, (trans_m, rot_deg)
    record = rig.get(f"/api/sessions/{DISASTER_RESPONSE_NAME}/results/{result.group(1)}")
    assert record["method"] == "vtarget" and record["verdict"]["level"] == "trusted"
    trans_m, rot_deg = transform_error(np.array(record["T_parent_child"]), T_CAMERA_LIVOX_TRUE)
    assert np.abs(trans_m).max() < 0.005 and np.abs(rot_deg).max() < 0.1, (trans_m, rot_deg)
