"""Step 9 of the real studio on the simulated depth cell, driven through Debian chromium: one node walked through
the guided procedure, its frames taken over Zenoh from a node agent in its own process.

The session is the depth-cell demo's (:func:`backend.services.demo_depth_cell.ensure_depth_cell_session`,
built in the fixture) served by ``calib-studio serve``; the six agents of ``demo --rig depth-cell`` would
cost two cores minutes, so one agent (``sn1``) connects to the studio, which listens from the nodes panel
(*Listen for nodes*). Node ``sn1`` is started from a typed pose (the truth off by 4-5 cm and about 2 degrees,
as a tape measure leaves it); for the tables behind and beside each other the simulated tables are placed
(*Place tables (simulation)*, over Zenoh to the agent) and the node captured, the suggestion is applied and
the step's done tick appears with every table height within 5 mm of its known 0.74 m; the lines step
brings every floor line within 5 mm. Through the HTTP API the guided pose is within 10 mm and 0.1 degrees
of the truth (truth.json), and the result kept from it is a ``depth_node`` result of method ``guided``.
"""

from __future__ import annotations

import contextlib
import json
import re
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path
from types import SimpleNamespace

import httpx
import numpy as np
import pytest
import viser
from playwright.sync_api import Browser, Page, expect

from backend.calib.depth import service as network_service
from backend.core.depth_cell import PAPER_NODE_POSES, default_cell_layout
from backend.core.transforms import transform_error
from backend.devices.node_keys import load_network_keys
from backend.services.demo_depth_cell import DEPTH_CELL_NAME, TRUTH_FILE, ensure_depth_cell_session
from backend.services.jobs import JobRunner
from backend.services.node_processes import NodeProcesses, free_tcp_port
from backend.store.session import SessionStore
from studio.app import StudioApp
from tests.conftest import (
    ARTIFACTS,
    Studio,
    button,
    choose,
    poll,
    serving,
    studio_page,
    text_input,
    wait_body,
)

pytestmark = [pytest.mark.browser, pytest.mark.slow]

VIEWPORT = {"width": 1600, "height": 2600}
NODE = "sn1"
TYPED = dict(zip(("X (m)", "Y (m)", "Z (m)", "RotZ (°)", "RotY (°)", "RotX (°)"),
                 np.add(PAPER_NODE_POSES[NODE], (0.03, -0.02, 0.03, 1.5, 0.5, -1.0)).round(3), strict=True))
"""The pose typed in step 1: the truth off by 4.7 cm and about 1.9 degrees."""
AGENT_RATE_HZ = 1.0
"""The agent's stream (frames/s): the presence table shows it; captures are full frames on request."""
API = f"/api/sessions/{DEPTH_CELL_NAME}/depth-network"
TABLE_TOLERANCE_M = 0.005
GUIDED_TOLERANCE = (0.010, 0.1)
"""The guided pose against the truth: m, deg (the issue's 10 mm)."""
PRISTINE = "pristine"
"""The fixture's folder holding the session as built (the served copy is changed by the browser test)."""
PICK_TOLERANCE_M = 0.1
"""A cross picked at the tape-measured poses (4-5 cm and 1-2 degrees off at 5 m range) against its true position."""


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory, free_port: Callable[[], int]) -> Iterator[Studio]:
    """``calib-studio serve`` on a folder holding the depth-cell session (built here, without agents)."""
    tmp = tmp_path_factory.mktemp("depth_studio")
    ensure_depth_cell_session(SessionStore(tmp / PRISTINE))
    shutil.copytree(tmp / PRISTINE, tmp / "sessions")
    with serving(tmp / "sessions", free_port, tmp / "studio.log", ("serve",)) as studio:
        yield studio


def _heights_within(page: Page, tolerance_m: float) -> list[float]:
    """The errors (mm) of the residual table on show; asserts every one is within ``tolerance_m``."""
    table = page.locator("table", has_text="measured (m)").filter(visible=True)
    rows = table.locator("tbody tr")
    errors = [float(rows.nth(i).locator("td").nth(5).inner_text()) for i in range(rows.count())]
    assert errors and all(abs(e) <= 1000 * tolerance_m for e in errors), errors
    return errors


def _apply_until_done(page: Page, shot: str) -> None:
    """Click the step's suggestion and wait for its done tick; the screenshot ``shot``."""
    apply = page.get_by_role("button", name=re.compile(r"^Apply ")).filter(visible=True)
    expect(apply).to_be_enabled()
    apply.click()
    expect(page.get_by_text("Done", exact=True).filter(visible=True)).to_be_visible()
    page.screenshot(path=ARTIFACTS / shot)


def _tables_step(page: Page, label: str, shot: str) -> None:
    """Place the simulated tables for the step, capture the node, apply the suggestion until done."""
    expect(page.get_by_label("Guided step", exact=True)).to_have_value(label)
    button(page, "Place tables (simulation)").click()
    wait_body(page, re.compile(r"Tables placed (behind|beside) each other"))
    button(page, "Capture this node").click()
    wait_body(page, re.compile(r"Stored 1 capture\(s\)"))
    _apply_until_done(page, shot)
    _heights_within(page, TABLE_TOLERANCE_M)
    button(page, "Next step").click()


def test_one_node_through_the_guided_procedure(browser: Browser, cell: Studio, tmp_path: Path) -> None:
    endpoint = f"tls/127.0.0.1:{free_tcp_port()}"
    with studio_page(browser, cell.url, VIEWPORT) as page, contextlib.ExitStack() as stack:
        choose(page, "Session", DEPTH_CELL_NAME)
        button(page, "Open session").click()
        listen = text_input(page, "Listen on")  # step 9 shows, unfolded, once a rig with depth nodes is open
        expect(listen).to_be_visible()
        listen.fill(endpoint)
        listen.press("Enter")
        button(page, "Make the nodes' keys").click()  # in the session's folder, one file per rig node
        wait_body(page, re.compile(rf"{NODE}: {NODE}.keys.pem: calib-studio node --name {NODE} --keys"))
        button(page, "Listen for nodes").click()
        wait_body(page, re.compile(r"secured with keys \w+ on tls/127.0.0.1:\d+: only sn1, .*sn6 can join"))
        keys = load_network_keys(cell.log.parent / "sessions" / DEPTH_CELL_NAME / "network-keys")
        agents = stack.enter_context(NodeProcesses(endpoint, tmp_path, rate_hz=AGENT_RATE_HZ, keys=keys))
        agents.start({NODE: f"sim-cell:{NODE}"})
        wait_body(page, re.compile(rf"{NODE}\s+alive\s+sim-cell:{NODE}"))  # through Zenoh liveliness
        page.screenshot(path=ARTIFACTS / "studio_depth_nodes.png")

        for label, value in TYPED.items():
            box = text_input(page, label)
            box.fill(str(value))
            box.press("Enter")
        button(page, "Start from this pose").click()
        _tables_step(page, "2 · Tables behind each other", "studio_depth_behind.png")
        _tables_step(page, "3 · Tables beside each other", "studio_depth_beside.png")
        expect(page.get_by_label("Guided step", exact=True)).to_have_value("4 · Lines and points")
        _apply_until_done(page, "studio_depth_lines.png")
        _heights_within(page, TABLE_TOLERANCE_M)  # the lines' distances, same tolerance
        button(page, "Keep this pose as the node's result").click()
        result_id = wait_body(page, re.compile(r"Kept as (r\d+) \(guided, verdict trusted\)"), timeout_s=90).group(1)
        wait_body(page, re.compile(rf"{result_id} \(not accepted\) · depth_node · guided"))
        page.screenshot(path=ARTIFACTS / "studio_depth_result.png")
        page.get_by_role("button", name="Accept", exact=True).filter(visible=True).last.click()
        page.get_by_role("button", name="Confirm accept", exact=True).filter(visible=True).click()
        wait_body(page, re.compile(rf"{result_id} \(accepted\)"))
        page.screenshot(path=ARTIFACTS / "studio_depth_accepted.png")

    state = httpx.get(f"{cell.api}{API}/guided/{NODE}", timeout=30).json()
    assert state["done"] == ["initial", "tables_behind", "tables_beside", "lines"], state
    assert state["result_id"] == result_id
    summary = httpx.get(f"{cell.api}{API}/summary", timeout=30).json()
    assert summary["nodes"][NODE]["result_id"] == result_id, summary["nodes"][NODE]
    truth = np.array(json.loads((cell.log.parent / "sessions" / DEPTH_CELL_NAME / TRUTH_FILE).read_text())["nodes"][
        NODE]["T_world_node"])
    # The guided pose, and the rig's once accepted (fused with the tape-measured prior, which pulls it by ~0.1 mm).
    for what, T in (("guided", state["T_world_node"]), ("rig", summary["nodes"][NODE]["T_world_node"])):
        dt_m, dr_deg = transform_error(np.array(T), truth)
        assert np.linalg.norm(dt_m) <= GUIDED_TOLERANCE[0] and np.linalg.norm(dr_deg) <= GUIDED_TOLERANCE[1], (
            what, dt_m, dr_deg)


def test_network_panel_in_process(cell: Studio, tmp_path: Path, free_port: Callable[[], int]) -> None:
    """The network folder on the session as built (tape-measured poses), in an in-process studio: the merged map
    drawn in the step's layer, a click's ray from above a cross picks that cross, and the verification row of two
    detected crosses is the service's."""
    shutil.copytree(cell.log.parent / PRISTINE, tmp_path / "sessions")
    store = SessionStore(tmp_path / "sessions")
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    jobs = JobRunner()
    try:
        app = StudioApp(server, store, jobs, session=store.get(DEPTH_CELL_NAME))
        step, session = app.depth_network_step, app.ctx.session
        assert step.folder.visible and step.node.value == "sn1"
        voxels = network_service.merged_voxel_map(session)
        step._draw_map()
        step.map_jobs.job.wait(120)
        nodes = server.scene._handle_from_node_name
        poll(lambda: "/steps/depth_network/map" in nodes, "the merged map was never drawn",  # drawn by on_done,
             interval_s=0.1)                                                                   # on a watcher thread
        assert len(np.asarray(nodes["/steps/depth_network/map"].points)) == len(voxels.counts)
        assert {f"/steps/depth_network/cell/line_labels/{line.name}" for line in default_cell_layout().lines} <= set(
            nodes)

        cross = default_cell_layout().cross("robot_b1")
        step._arm_pick()
        (entry,) = server.scene._scene_pointer_cb
        entry.callback(SimpleNamespace(ray_origin=np.add(cross.position_m, (0.0, 0.0, 6.0)),
                                       ray_direction=(0.0, 0.0, -1.0)))
        assert step._picked["name"] == "robot_b1", step.pick_text.content
        assert np.linalg.norm(np.subtract(step._picked["point_m"], cross.position_m)) <= PICK_TOLERANCE_M
        assert not server.scene._scene_pointer_cb  # one click picks one point

        step.point_a.value, step.point_b.value = "robot_b1", "robot_b2"
        step.measured.value = 1.555
        step._work(step._verify)
        (row,) = network_service.verification_rows(session)
        assert (row["a"], row["b"], row["measured_m"]) == ("robot_b1", "robot_b2", 1.555)
        assert f"{row['estimated_m']:.3f} | {1000 * row['error_m']:+.1f}" in step.verification_text.content

        # Solve all nodes: solved, previewed, nothing accepted until confirmed
        accepted = session.accepted_slots()
        step._solve_all()
        text = poll(lambda: "Nothing is accepted yet" in step.solve_jobs.text.content and step.solve_jobs.text.content,
                    "the network solve never reported", 300)  # the button is set before this text
        assert session.accepted_slots() == accepted and step.accept_all_button.visible, text
        trusted = step._to_accept
        assert trusted and f"**Accepting the {len(trusted)} trusted result(s) would:**" in text, text
        step._work(step._accept_all)
        assert set(trusted) <= set(session.accepted_slots().values()) and not step.accept_all_button.visible
        assert step.solve_jobs.text.content.startswith(f"**Accepted {', '.join(trusted)}.**")
        app.close()
    finally:
        jobs.shutdown()
        server.stop()
