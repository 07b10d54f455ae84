"""Adding a simulated network LiDAR in the sensors step and streaming it, then the swept-scanner step,
in the real studio (``calib-studio demo`` in a subprocess) driven through Debian chromium.

The Velodyne is picked in the form with ``Source: sim`` (its byte-level simulator sends VLP-16 packets
over UDP on 127.0.0.1); the swept scanner is the demo rig's ``sweep_3d`` (a ray-cast 2D scanner on a
simulated Dynamixel servo, on a pty) with a nominal geometry, calibrated and accepted in the page and
checked through the HTTP API against the simulator's truth. One studio process and one page serve the module, its
tests in their order; each opens the folders it works in.
"""

from __future__ import annotations

import re
from collections.abc import Iterator

import numpy as np
import pytest
from playwright.sync_api import Browser, Page, expect
from rosbags.rosbag2 import StoragePlugin

from backend.core.sweep_geometry import SweepGeometry
from backend.sim.demo_rig import DEFAULT_SIM_GEOMETRY
from tests.conftest import (
    ARTIFACTS,
    Studio,
    assert_uncovered,
    button,
    choose,
    close_toast,
    studio_page,
    text_input,
    unfold,
    wait_body,
)
from tests.devices.test_rosbag_source import write_bag

pytestmark = [pytest.mark.browser, pytest.mark.slow]

VIEWPORT = {"width": 1600, "height": 2000}
VELO_LIVE_RE = re.compile(r"velo_sim\s+(?!0\.0 )([\d.]+) Hz, ([\d,]+) pts drawn")
"""velo_sim streaming: a rate needs two turns, so the first turn drawn shows 0.0 Hz and is waited past."""
SWEEP_RESULT_RE = re.compile(r"(r\d{4}) \(not accepted\) · sweep · [\d.]+ s")
TRUTH = SweepGeometry.from_dict(DEFAULT_SIM_GEOMETRY)


@pytest.fixture(scope="module")
def page(browser: Browser, studio: Studio) -> Iterator[Page]:
    """One page for the module's tests: opening one costs chromium about 5 s of CPU, and the GUI's state is the
    server's whichever page shows it."""
    with studio_page(browser, studio.url, VIEWPORT) as page:
        yield page


def _sensor_form(page: Page, name: str, kind: str, device: str) -> None:
    """Open the sensors step and fill in a new sensor's name, kind and device."""
    box = text_input(page, "Name")
    unfold(page, "2 · Sensors", box)
    box.fill(name)
    box.press("Enter")
    choose(page, "Kind", kind)
    choose(page, "Device", device)


def test_add_a_simulated_velodyne_and_stream_it(page: Page, studio: Studio) -> None:
    _sensor_form(page, "velo_sim", "lidar3d", "velodyne")
    expect(text_input(page, "Source")).to_have_value("sim")
    expect(page.get_by_text("Velodyne VLP-16 over UDP", exact=False)).to_be_visible()
    button(page, "Add sensor").click()
    wait_body(page, re.compile(r"velo_sim \(lidar3d\) under base_link · velodyne"))
    frames = {f["name"]: f for f in studio.get("/api/sessions/demo/rig")["frames"]}
    assert frames["velo_sim"]["device"] == {"driver": "velodyne", "host": "sim"}

    _stream_and_capture(page, studio)


def _stream_and_capture(page: Page, studio: Studio) -> None:
    close_toast(page, "Sensor added")  # it floats over the panel and would take the clicks
    unfold(page, "4 · LiDARs", button(page, "Start live"))
    button(page, "Start live").scroll_into_view_if_needed()
    # Adding velo_sim changed the closed step's live boxes: a titled viser folder filled while closed can stay at
    # height 0, its frame covering them; the boxes sit in an untitled one, so nothing covers them.
    assert_uncovered(page.get_by_label("lidar_top", exact=True))
    for name in ("lidar_top", "lidar_front", "scanner_2d", "sweep_3d"):
        page.get_by_label(name, exact=True).uncheck()
    page.get_by_label("velo_sim", exact=True).check()
    button(page, "Start live").click()
    match = wait_body(page, VELO_LIVE_RE)
    # It streams whole turns; its 10 Hz (the packets' own clock) is test_velodyne's, the page's speed a benchmark's.
    assert float(match.group(1)) > 0 and int(match.group(2).replace(",", "")) > 10_000, match.group(0)
    button(page, "Capture clouds").click()
    wait_body(page, re.compile(r"velo_sim: 1"))
    ARTIFACTS.mkdir(exist_ok=True)
    page.screenshot(path=ARTIFACTS / "studio_velodyne_sim.png")
    button(page, "Stop live").click()
    expect(button(page, "Start live")).to_be_visible()
    [capture] = studio.get("/api/sessions/demo/sensors/velo_sim/captures")
    print(f"velo_sim live: {match.group(0)}; captured {capture['n_points']:,} points")
    assert capture["n_points"] > 20_000 and capture["device"].startswith("velodyne VLP-16 sim")


def test_import_a_bag_topic(page: Page, studio: Studio, tmp_path) -> None:
    bag = write_bag(tmp_path / "drive", StoragePlugin.MCAP)
    _sensor_form(page, "bag_lidar", "lidar3d", "rosbag")
    # Type once the form shows the bag's fields: the server's answer to the device choice (its example source)
    # is then on the page, and cannot land on the typed path.
    list_topics = button(page, "List the bag's topics")
    expect(list_topics).to_be_visible()
    source = text_input(page, "Source")
    source.fill(str(bag))
    source.press("Enter")
    expect(source).to_have_value(str(bag))
    list_topics.click()
    wait_body(page, re.compile(r"/lidar/points\s+PointCloud2\s+3"))
    expect(text_input(page, "Topic")).to_have_value("/lidar/padded")  # the first topic a LiDAR can replay
    topic = text_input(page, "Topic")
    topic.fill("/lidar/points")
    topic.press("Enter")
    button(page, "Add sensor").click()
    wait_body(page, re.compile(r"bag_lidar \(lidar3d\) under base_link · rosbag"))

    close_toast(page, "Sensor added")  # it floats over the panel
    unfold(page, "4 · LiDARs", button(page, "Start live"))
    unfold(page, "Import", page.get_by_label("Into LiDAR", exact=True))
    choose(page, "Into LiDAR", "bag_lidar")
    wait_body(page, re.compile(r"Recording: rosbag · path .*drive, topic /lidar/points"))
    button(page, "Import its recording").click()
    wait_body(page, re.compile(r"3 scans into bag_lidar; end of bag after 3 messages"))
    page.screenshot(path=ARTIFACTS / "studio_bag_import.png")
    captures = studio.get("/api/sessions/demo/sensors/bag_lidar/captures")
    assert [c["source"] for c in captures] == ["/lidar/points #0", "/lidar/points #1", "/lidar/points #2"]


def test_calibrate_the_swept_scanner(page: Page, studio: Studio) -> None:
    scanner = page.get_by_label("Swept scanner", exact=True)
    unfold(page, "5 · Swept scanner", scanner)
    expect(scanner).to_have_value("sweep_3d")
    button(page, "Capture sweep").click()
    wait_body(page, re.compile(r"1 sweep\(s\) captured"), timeout_s=240)  # a whole servo sweep, on a loaded machine
    button(page, "Calibrate").click()
    match = wait_body(page, SWEEP_RESULT_RE, timeout_s=120)
    result_id = match.group(1)
    # the result card (the scanner's pose at servo zero, its sigma, the verdict) and the sweep's own panel
    wait_body(page, re.compile(r"sweep_3d → sweep_3d_scanner: .* m · .*\s+1σ: n/a, \d+\.\d+, \d+\.\d+ mm"))
    wait_body(page, re.compile("Sweep geometry · "))  # sent after the card: it can arrive later
    body = page.inner_text("body")
    for text in ("Verdict:", "Sweep geometry · ", "Optical centre in the servo frame (mm)", "servo zero offset (°)",
                 "Estimated (1σ): offset u ± ", "rms_after "):
        assert text in body, f"{text!r} missing from the result"
    page.get_by_text("The sweep as a LiDAR image", exact=False).scroll_into_view_if_needed()
    page.screenshot(path=ARTIFACTS / "studio_sweep.png")

    # the card's Accept (the one after this step's Calibrate) first previews what the rig would do, then applies
    calibrate = button(page, "Calibrate")
    calibrate.locator("xpath=following::button[normalize-space(.)='Accept'][1]").click()
    wait_body(page, re.compile(rf"Accepting {result_id} would:"))
    calibrate.locator("xpath=following::button[normalize-space(.)='Confirm accept'][1]").click()
    wait_body(page, re.compile(rf"{result_id} \(accepted\)"))
    page.screenshot(path=ARTIFACTS / "studio_sweep_accepted.png")

    record = studio.get(f"/api/sessions/demo/results/{result_id}")
    assert studio.get("/api/sessions/demo")["accepted"]["sweep_3d/sweep"] == result_id
    assert record["transform"]["parent"] == "sweep_3d" and record["transform"]["child"] == "sweep_3d_scanner"
    frames = {f["name"]: f for f in studio.get("/api/sessions/demo/rig")["frames"]}
    assert frames["sweep_3d"]["device"]["geometry"] == record["geometry"]
    found = SweepGeometry.from_dict(record["geometry"])
    offset_error_m = found.T_servo_scanner[:3, 3] - TRUTH.T_servo_scanner[:3, 3]
    zero_error_deg = np.degrees(found.zero_offset_rad - TRUTH.zero_offset_rad)
    print(f"{result_id}: offset error {1000 * offset_error_m} mm, zero offset error {zero_error_deg:.3f} deg, "
          f"plane RMS {1000 * record['rms_before_m']:.1f} -> {1000 * record['rms_after_m']:.1f} mm")
    assert record["rms_after_m"] < record["rms_before_m"]
    assert abs(zero_error_deg) < 0.1
    # the offset along the servo axis (x) cannot be seen by planarity; across it, it is recovered
    assert np.abs(offset_error_m[1:]).max() < 0.003


def test_remove_a_sensor_and_restore_it(page: Page, studio: Studio) -> None:
    """lidar_top (the demo's board pairs' LiDAR) is removed after its preview, kept aside with its captures, and
    restored from *Removed sensors*."""
    captures = [c["id"] for c in studio.get("/api/sessions/demo/sensors/lidar_top/captures")]
    assert captures, "the demo holds lidar_top's board pairs"
    unfold(page, "2 · Sensors", page.get_by_label("Sensor", exact=True))
    choose(page, "Sensor", "lidar_top")
    expect(text_input(page, "Name")).to_have_value("lidar_top")
    button(page, "Remove sensor…").click()
    wait_body(page, re.compile(r"Removing lidar_top: its captures and results are kept aside"))
    expect(button(page, "Confirm removal")).to_be_visible()
    page.screenshot(path=ARTIFACTS / "studio_sensor_remove_preview.png")
    assert "lidar_top" in studio.get("/api/sessions/demo")["sensors"], "a preview removed the sensor"

    button(page, "Confirm removal").click()
    wait_body(page, re.compile(r"Removed lidar_top, kept aside as lidar_top-1"))
    assert "lidar_top" not in studio.get("/api/sessions/demo")["sensors"]
    expect(page.get_by_text(re.compile(r"^lidar_top \(lidar3d\) under base_link"))).to_have_count(0)
    unfold(page, "Removed sensors", page.get_by_label("Removal", exact=True))
    wait_body(page, re.compile(rf"lidar_top-1: lidar_top \(lidar3d\), {len(captures)} capture\(s\)"))
    page.screenshot(path=ARTIFACTS / "studio_sensor_removed.png")

    choose(page, "Removal", "lidar_top-1")
    button(page, "Restore sensor").click()
    wait_body(page, re.compile(r"Restored lidar_top"))
    expect(text_input(page, "Name")).to_have_value("lidar_top")
    page.screenshot(path=ARTIFACTS / "studio_sensor_restored.png")
    assert "lidar_top" in studio.get("/api/sessions/demo")["sensors"]
    assert [c["id"] for c in studio.get("/api/sessions/demo/sensors/lidar_top/captures")] == captures
    assert studio.get("/api/sessions/demo/removed") == []
